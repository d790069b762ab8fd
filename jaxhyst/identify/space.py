"""Which parameters are free, their bounds, and the coordinates the solvers work in.

A `ParameterSpace` maps between four views of the unknowns:

- the **parameters** themselves: any pytree of float arrays — `Parameters` (one set, or
  one per loop of a joint problem), or a user's own pytree;
- the **free values** x (SI units, shape (n,)): the entries being identified;
- **box coordinates** u ∈ [0, 1]ⁿ, x = lower + (upper − lower)·u — the GA's;
- **solver coordinates** z ∈ ℝⁿ with the periodic map u = (1 + sin z)/2 (as in MINUIT and
  lmfit): every z maps inside the box, so bounds hold by construction for any
  unconstrained solver, and unlike a sigmoid the map never saturates (SPEC §5).

Internally the parameters are a flat vector ``base`` (every element of every leaf); each
free value is written to one or more flat positions (more than one for a parameter
shared by several loops). Parameters not listed as free are held at their values,
exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._typing import Array, ArrayLike, Float
from ..model.losses import LOSS_NAMES, Losses
from ..model.paths import own_parameters
from ..names import base_name
from ..params import NAMES, Bounds, Parameters, check_value


def u_from_z(z: Float[ArrayLike, "*batch n"]) -> Float[Array, "*batch n"]:
    """Box coordinate u ∈ [0, 1] from the unconstrained z (periodic sine map)."""
    return 0.5 * (1.0 + jnp.sin(z))


def z_from_u(u: Float[ArrayLike, "*batch n"]) -> Float[Array, "*batch n"]:
    """The z ∈ [−π/2, π/2] that maps to u (inverse of `u_from_z` on its principal branch)."""
    return jnp.arcsin(jnp.clip(2.0 * jnp.asarray(u) - 1.0, -1.0, 1.0))


def _leaf_name(path) -> str:
    """A readable name for a pytree path: ``Ms``, ``coil.R``, ``gains[2]``."""
    parts = []
    for key in path:
        if isinstance(key, jax.tree_util.GetAttrKey):
            parts.append(("." if parts else "") + key.name)
        elif isinstance(key, jax.tree_util.DictKey):
            parts.append(("." if parts else "") + str(key.key))
        elif isinstance(key, jax.tree_util.SequenceKey):
            parts.append(f"[{key.idx}]")
        else:
            parts.append(str(key))
    return "".join(parts) or "x"


class ParameterSpace(eqx.Module):
    """Free parameters with box bounds; the others fixed (see the module docstring).

    **Arguments** (for `Parameters`; `for_tree` and `for_loops` build the other kinds):
    - ``bounds``: `Bounds` for all ten parameters (only the free ones' are used).
    - ``fixed``: ``{name: value}`` of parameters held fixed (SI units); default none.
    """

    lower: jax.Array  # (n,) SI
    upper: jax.Array  # (n,) SI
    base: jax.Array  # (D,) every flat entry; free ones are overwritten
    positions: tuple[int, ...] = eqx.field(static=True)  # flat entries set from x …
    which: tuple[int, ...] = eqx.field(static=True)  # … by these free indices
    names: tuple[str, ...] = eqx.field(static=True)  # free names, order of x
    flat_names: tuple[str, ...] = eqx.field(static=True)  # name of every flat entry
    treedef: object = eqx.field(static=True)
    shapes: tuple = eqx.field(static=True)  # leaf shapes

    def __init__(self, bounds: Bounds, fixed: dict[str, float] | None = None):
        if not isinstance(bounds, Bounds):
            raise TypeError(f"bounds must be jaxhyst.Bounds; got {type(bounds).__name__} "
                            "(for another pytree of parameters use ParameterSpace.for_tree).")
        if fixed and not isinstance(fixed, Mapping):
            example = ", ".join(f"{n!r}: …" for n in list(fixed)[:2]) if isinstance(
                fixed, (list, tuple, set)) else "'Ms': 7.65e5"
            raise TypeError(f"fixed needs the values to hold, as {{name: value}} in SI units "
                            f"(e.g. {{{example}}}); got {type(fixed).__name__}. "
                            "(synthetic_problem takes a list of names and holds the true "
                            "values.)")
        fixed = dict(fixed or {})
        unknown = [n for n in fixed if n not in NAMES]
        if unknown:
            raise ValueError(f"Cannot fix unknown parameter(s) {unknown}; names are {list(NAMES)}.")
        lo = np.asarray(bounds.lower.to_array(), dtype=float)
        hi = np.asarray(bounds.upper.to_array(), dtype=float)
        base = 0.5 * (lo + hi)
        for n, v in fixed.items():
            base[NAMES.index(n)] = check_value(n, v, f"fixed value of {n}")
        free = [i for i, n in enumerate(NAMES) if n not in fixed]
        self._set(lo[free], hi[free], base, free, list(range(len(free))),
                  [NAMES[i] for i in free], list(NAMES),
                  jax.tree.structure(bounds.lower), ((),) * len(NAMES))

    def _set(self, lower, upper, base, positions, which, names, flat_names, treedef, shapes):
        if not names:
            raise ValueError("Every parameter is fixed: there is nothing to identify. Free "
                             "at least one parameter.")
        bad = [n for n, lo, hi in zip(names, lower, upper, strict=True)
               if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi)]
        if bad:
            raise ValueError(f"Bounds of {bad} must be finite with lower <= upper.")
        values = dict(lower=jnp.asarray(lower, dtype=jnp.float64),
                      upper=jnp.asarray(upper, dtype=jnp.float64),
                      base=jnp.asarray(base, dtype=jnp.float64),
                      positions=tuple(int(i) for i in positions),
                      which=tuple(int(i) for i in which), names=tuple(names),
                      flat_names=tuple(flat_names), treedef=treedef,
                      shapes=tuple(tuple(s) for s in shapes))
        for k, v in values.items():  # (also used on instances made without __init__)
            object.__setattr__(self, k, v)

    # -- other kinds of parameters -----------------------------------------------------------
    @classmethod
    def for_tree(cls, lower, upper, fixed: dict | None = None, values=None) -> ParameterSpace:
        """A space over any pytree of float arrays: ``lower`` and ``upper`` have its
        structure (SI values). ``fixed``: ``{name: value}`` for entries held fixed (names as
        in `names`, e.g. ``"gain"``, ``"coil.R"``, ``"w[2]"``), or ``values``: a pytree of
        the same structure whose entries are used for the fixed names given as a list."""
        lo_leaves, treedef = jax.tree_util.tree_flatten_with_path(lower)
        hi_leaves = jax.tree.leaves(upper)
        if len(hi_leaves) != len(lo_leaves) or jax.tree.structure(upper) != treedef:
            raise ValueError("lower and upper bounds must be pytrees of the same structure.")
        names, lo, hi, shapes = [], [], [], []
        for (path, a), b in zip(lo_leaves, hi_leaves, strict=True):
            a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            if a.shape != b.shape:
                raise ValueError(f"Bounds of {_leaf_name(path)} have shapes {a.shape} and "
                                 f"{b.shape}.")
            shapes.append(a.shape)
            name = _leaf_name(path)
            names += [name] if a.ndim == 0 else [f"{name}[{i}]" for i in range(a.size)]
            lo.append(a.ravel())
            hi.append(b.ravel())
        lo, hi = np.concatenate(lo), np.concatenate(hi)
        base = 0.5 * (lo + hi)
        if values is not None:
            base = np.concatenate([np.ravel(np.asarray(v, dtype=float))
                                   for v in jax.tree.leaves(values)])
        if isinstance(fixed, (list, tuple, set)):
            fixed = {n: base[names.index(n)] for n in fixed if n in names}
        fixed = dict(fixed or {})
        unknown = [n for n in fixed if n not in names]
        if unknown:
            raise ValueError(f"Cannot fix unknown parameter(s) {unknown}; names are {names}.")
        for n, v in fixed.items():
            base[names.index(n)] = check_value("", v, f"fixed value of {n}")  # (any tree: finite)
        free = [i for i, n in enumerate(names) if n not in fixed]
        space = object.__new__(cls)
        space._set(lo[free], hi[free], base, free, list(range(len(free))),
                   [names[i] for i in free], names, treedef, shapes)
        return space

    @classmethod
    def with_losses(cls, bounds: Bounds, losses: Mapping, fixed: dict | None = None
                    ) -> ParameterSpace:
        """A space over the pair ``(Parameters, Losses)`` of the rate-dependent model: the
        ten parameters as ``ParameterSpace(bounds, fixed)``, and the loss coefficients
        ``eddy``, ``excess`` and ``lag`` (`jaxhyst.Losses`) in the box ``losses``
        ``{name: (lower, upper)}`` (SI; a coefficient left out is held at 0). ``fixed``
        may name them too. (`for_model` with ``losses``.)"""
        return cls.for_model(bounds, fixed=fixed, losses=losses)

    @classmethod
    def for_loops(cls, bounds: Bounds, n_loops: int, per_loop: Sequence[str] = (),
                  fixed: dict | None = None) -> ParameterSpace:
        """Parameters of L loops (a `Parameters` with leaves of shape (L,)): each name is
        **shared** by all loops, **per loop** (``per_loop``; free entries ``a[2]`` …) or
        **fixed** (``{name: value}`` or ``{name: [v_0 … v_L-1]}``). Free entries: the
        shared ones in `NAMES` order, then each per-loop name for loop 0 … L-1.
        (`for_model` with ``n_loops``.)"""
        return cls.for_model(bounds, fixed=fixed, n_loops=n_loops, per_loop=per_loop)

    @classmethod
    def for_model(cls, bounds: Bounds, *, fixed: dict | None = None,
                  losses: Mapping | None = None, form=None, own: Mapping | None = None,
                  n_loops: int | None = None, per_loop: Sequence[str] = ()
                  ) -> ParameterSpace:
        """A space over a model's parameter pytree (`jaxhyst.model.paths.split_parameters`):
        the ten `Parameters` in ``bounds``; with ``losses`` (``{"eddy": (lower, upper),
        …}``, SI; a coefficient left out is held at 0) also `jaxhyst.Losses`; with a
        ``form`` that has parameters of its own (`jaxhyst.PlayJA`: ``spread``) also that
        form, its parameters in the box ``own`` (``{name: (lower, upper)}``) or the form's
        default box. ``n_loops``: L loops, every leaf of shape (L,), each name **shared**
        by all loops, **per loop** (``per_loop``: free entries ``a[2]`` …) or **fixed**;
        None: one set. ``fixed``: ``{name: value}`` (a value per loop allowed)."""
        fixed = dict(fixed or {})
        lo = dict(zip(NAMES, np.asarray(bounds.lower.to_array(), float).tolist(), strict=True))
        hi = dict(zip(NAMES, np.asarray(bounds.upper.to_array(), float).tolist(), strict=True))
        members = [_TEMPLATE]
        if losses is not None:
            unknown = sorted(set(losses) - set(LOSS_NAMES))
            if unknown:
                raise ValueError(f"losses: unknown coefficients {unknown}; they are "
                                 f"{list(LOSS_NAMES)} ({{name: (lower, upper)}}, SI).")
            for n in LOSS_NAMES:
                a, b = (float(v) for v in losses.get(n, (0.0, 0.0)))
                if not (np.isfinite(a) and np.isfinite(b) and 0 <= a <= b):
                    raise ValueError(f"losses[{n!r}] = ({a}, {b}): the box of a loss "
                                     "coefficient needs 0 <= lower <= upper, finite (SI).")
                lo[n], hi[n] = a, b
                if n not in losses:
                    fixed.setdefault(n, 0.0)
            members.append(Losses())
        own_names = own_parameters(form) if form is not None else {}
        if own and not own_names:
            raise ValueError(f"own: {sorted(own)} are parameters of no form here; give the "
                             "form that has them (form=PlayJA() …).")
        if own_names:
            unknown = sorted(set(own or {}) - set(own_names))
            if unknown:
                raise ValueError(f"own: {type(form).__name__} has no parameters {unknown} "
                                 f"(its own: {sorted(own_names)}).")
            for n in own_names:
                lo[n], hi[n] = (float(v) for v in (own or {}).get(n,
                                                                   form.own_bounds(bounds)[n]))
            members.append(form)
        template = members[0] if len(members) == 1 else tuple(members)
        names = [_leaf_name(path).rsplit(".", 1)[-1]
                 for path, _ in jax.tree_util.tree_flatten_with_path(template)[0]]
        bad = [n for n in (*per_loop, *fixed) if n not in names]
        if bad:
            raise ValueError(f"Unknown parameter(s) {bad}; names are {names}.")
        both = sorted(set(per_loop) & set(fixed))
        if both:
            raise ValueError(f"{both} cannot be both per-loop and fixed.")
        L = None if n_loops is None else int(n_loops)
        if L is not None and L < 1:
            raise ValueError("A joint problem needs at least one loop.")
        if L is None and per_loop:
            raise ValueError("per_loop needs n_loops (a space over several loops).")
        base = np.tile(np.array([0.5 * (lo[n] + hi[n]) for n in names])[:, None], (1, L or 1))
        for n, v in fixed.items():
            base[names.index(n)] = [_checked(n, x) for x in
                                    np.broadcast_to(np.asarray(v, float), (L or 1,))]
        positions, which, free, lower, upper = [], [], [], [], []
        for n in [n for n in names if n not in fixed and n not in per_loop] + list(per_loop):
            loops = range(L or 1)
            j = names.index(n)
            if n in per_loop:
                for l_ in loops:
                    positions.append(j * L + l_)
                    which.append(len(free))
                    free.append(f"{n}[{l_}]")
                    lower.append(lo[n])
                    upper.append(hi[n])
            else:
                positions += [j * (L or 1) + l_ for l_ in loops]
                which += [len(free)] * (L or 1)
                free.append(n)
                lower.append(lo[n])
                upper.append(hi[n])
        flat_names = names if L is None else [f"{n}[{l_}]" for n in names for l_ in range(L)]
        space = object.__new__(cls)
        space._set(lower, upper, base.ravel(), positions, which, free, flat_names,
                   jax.tree.structure(template), (() if L is None else (L,),) * len(names))
        return space

    # -- sizes and names ------------------------------------------------------------------
    @property
    def n_free(self) -> int:
        return len(self.names)

    @property
    def n_loops(self) -> int | None:
        """L for a space over per-loop `Parameters` (leaves of shape (L,)), else None."""
        shape = self.shapes[0] if self.shapes else ()
        return shape[0] if len(shape) == 1 and self._is_model() else None

    def _is_parameters(self) -> bool:
        return self.treedef == jax.tree.structure(_TEMPLATE)

    def _is_model(self) -> bool:
        """Whether the pytree is a model's parameters: `Parameters`, alone or first of a
        tuple (`for_model`)."""
        tree = jax.tree.unflatten(self.treedef, [0.0] * self.treedef.num_leaves)
        first = tree[0] if isinstance(tree, tuple) and tree else tree
        return isinstance(first, Parameters)

    # -- maps --------------------------------------------------------------------------------
    def flat_from_free(self, x) -> jax.Array:
        """Every flat entry (shape (..., D)) from the free values x (SI, shape (..., n))."""
        x = jnp.asarray(x)
        flat = jnp.broadcast_to(self.base, x.shape[:-1] + self.base.shape)
        return flat.at[..., np.asarray(self.positions)].set(
            x[..., np.asarray(self.which)])

    def params_from_free(self, x):
        """The parameter pytree with the free entries set to x (SI, shape (..., n));
        leaves get the leading batch axes of x."""
        flat = self.flat_from_free(x)
        batch = flat.shape[:-1]
        leaves, offset = [], 0
        for shape in self.shapes:
            size = int(np.prod(shape)) if shape else 1
            leaves.append(flat[..., offset:offset + size].reshape(batch + tuple(shape)))
            offset += size
        return jax.tree.unflatten(self.treedef, leaves)

    def free_values(self, params) -> jax.Array:
        """The free entries (SI, shape (n,)) of a parameter pytree (a shared entry is read
        from its last position). A `Parameters` with scalar leaves is accepted for a
        per-loop space (the same value in every loop). Traceable."""
        leaves = jax.tree.leaves(params)
        flat = jnp.concatenate([jnp.broadcast_to(jnp.asarray(a, jnp.float64), s).ravel()
                                for a, s in zip(leaves, self.shapes, strict=True)])
        return jnp.zeros(self.n_free, flat.dtype).at[np.asarray(self.which)].set(
            flat[np.asarray(self.positions)])

    def free_from_u(self, u) -> jax.Array:
        return self.lower + (self.upper - self.lower) * u

    def params_from_u(self, u):
        return self.params_from_free(self.free_from_u(u))

    def params_from_z(self, z):
        return self.params_from_u(u_from_z(z))

    def u_from_free(self, x) -> jax.Array:
        width = jnp.where(self.upper > self.lower, self.upper - self.lower, 1.0)
        return jnp.clip((jnp.asarray(x) - self.lower) / width, 0.0, 1.0)

    def u_from_params(self, params) -> jax.Array:
        """Box coordinates of the free entries of ``params`` (clipped into [0, 1])."""
        return self.u_from_free(self.free_values(params))

    def z_from_params(self, params) -> jax.Array:
        return z_from_u(self.u_from_params(params))

    def theta_from_u(self, u) -> jax.Array:
        """All flat values (SI, shape (..., D)) at box coordinates u."""
        return self.flat_from_free(self.free_from_u(u))

    # -- fixed values and bounds -----------------------------------------------------------
    @property
    def fixed(self) -> dict:
        """``{flat name: value}`` of the entries held fixed (per loop in a joint space: the
        value of the first loop when all loops share it)."""
        set_ = set(self.positions)
        base = np.asarray(self.base)
        out = {}
        for i, n in enumerate(self.flat_names):
            if i not in set_:
                out[n] = float(base[i])
        if self.n_loops:  # collapse "a[0]", "a[1]" … into "a" when equal
            L, merged = self.n_loops, {}
            for n in dict.fromkeys(base_name(f) for f in self.flat_names):
                vals = [out.get(f"{n}[{l_}]") for l_ in range(L)]
                if all(v is not None for v in vals):
                    merged[n] = vals[0] if len(set(vals)) == 1 else vals
            return merged
        return out

    def bounds(self) -> Bounds:
        """`Bounds` of all ten parameters (a fixed one's lower = upper = its value); for a
        space over one `Parameters` set."""
        if not self._is_parameters() or self.n_loops:
            raise ValueError("bounds() is defined for a space over one Parameters set.")
        lo, hi = np.array(self.base), np.array(self.base)
        lo[list(self.positions)] = np.asarray(self.lower)[list(self.which)]
        hi[list(self.positions)] = np.asarray(self.upper)[list(self.which)]
        return Bounds(Parameters.from_array(jnp.asarray(lo)),
                      Parameters.from_array(jnp.asarray(hi)))

    def with_fixed(self, fixed: dict) -> ParameterSpace:
        """This space with the free entries in ``fixed`` ({name: SI value}) also fixed."""
        unknown = [n for n in fixed if n not in self.names]
        if unknown:
            raise ValueError(f"{unknown} are not free parameters here (free: "
                             f"{list(self.names)}).")
        keep = [i for i, n in enumerate(self.names) if n not in fixed]
        base = np.array(self.base)
        for n, v in fixed.items():
            k = self.names.index(n)
            for pos, w in zip(self.positions, self.which, strict=True):
                if w == k:
                    base[pos] = check_value(base_name(n), v, f"fixed value of {n}")
        remap = {old: new for new, old in enumerate(keep)}
        pairs = [(pos, remap[w]) for pos, w in zip(self.positions, self.which, strict=True)
                 if w in remap]
        space = object.__new__(type(self))
        space._set(np.asarray(self.lower)[keep], np.asarray(self.upper)[keep], base,
                   [p for p, _ in pairs], [w for _, w in pairs],
                   [self.names[i] for i in keep], self.flat_names, self.treedef, self.shapes)
        return space

    def with_box(self, lower, upper) -> ParameterSpace:
        """The same space with other box bounds (SI, shape (n,)); traceable (a profile
        holds a parameter by lower = upper)."""
        return eqx.tree_at(lambda s: (s.lower, s.upper), self,
                           (jnp.asarray(lower), jnp.asarray(upper)))


_TEMPLATE = Parameters(*([0.0] * len(NAMES)))


def _checked(name: str, value) -> float:
    """A fixed value of ``name`` checked: a parameter's physical range, a loss coefficient
    >= 0, a form's own parameter finite and >= 0."""
    if name in NAMES:
        return check_value(name, value, f"fixed value of {name}")
    v = check_value("", value, f"fixed value of {name}")
    if v < 0:
        raise ValueError(f"fixed value of {name} = {v:g}: it must be >= 0.")
    return v


def JointSpace(bounds: Bounds, n_loops: int, per_loop: Sequence[str] = (),  # noqa: N802
               fixed: dict | None = None) -> ParameterSpace:
    """`ParameterSpace.for_loops` (the name this constructor had before spaces were one
    class)."""
    return ParameterSpace.for_loops(bounds, n_loops, per_loop, fixed)
