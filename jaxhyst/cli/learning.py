"""The learning side of ``jaxhyst compensate``: one step of iterative learning from a
measured run (``--measured``, ``--state``), or a rehearsal on a simulated actuator
(``--plant``)."""

from __future__ import annotations

from jaxhyst._interrupt import stop_requested

from .spec import CLIError, float_list, note, parameters_arg


def _measured(args, model, reference):
    """(applied input, measured displacement) at the reference's samples, from the run
    file of --measured (the last whole period of a longer periodic run)."""
    import numpy as np

    from jaxhyst.io import read_loops

    loops = read_loops(args.measured)
    if len(loops) != 1:
        raise CLIError(f"--measured {args.measured}: holds {len(loops)} loops; give one run.")
    loop = loops[0]
    if "y" not in loop.signals:
        raise CLIError(f"--measured {args.measured}: no displacement column y (m).")
    if model.actuator.n is not None:
        if loop.I is None:
            raise CLIError(f"--measured {args.measured}: no current column I (A), the input "
                           f"of {model.actuator.name}.")
        u = loop.I
    else:
        if loop.H is None:
            raise CLIError(f"--measured {args.measured}: no field column H (A/m), the input "
                           f"of {model.actuator.name}.")
        u = loop.H - float(model.actuator.Hb)
    y, N = loop.signals["y"], reference.n_samples
    if reference.periodic and u.shape[0] > N and u.shape[0] % N in (0, 1):
        R = u.shape[0] // N  # whole periods (a closing sample is dropped): averaged
        u, y = np.reshape(u[:R * N], (R, N)), np.reshape(y[:R * N], (R, N))
        if np.max(np.ptp(u, axis=0)) > 1e-6 * max(float(np.ptp(u)), 1e-300):
            raise CLIError(f"--measured {args.measured}: its {R} periods were driven by "
                           "different inputs; give the periods of one input.")
        u, y = u[0], y if R > 1 else y[0]
    if u.shape[0] != N:
        raise CLIError(f"--measured {args.measured}: {u.shape[0]} samples, but the reference "
                       f"has {N}{' per period' if reference.periodic else ''}; measure at its "
                       "samples.")
    return np.asarray(u, float), np.asarray(y, float)


def _plant(args, model, reference):
    """The simulated actuator of --plant (``model``'s actuator and form, the plant's
    parameters)."""
    import jaxhyst as jh
    from jaxhyst.control import SimulatedPlant

    mode = None
    if args.mode:
        values = float_list(args.mode, "--mode")
        if len(values) != 2:
            raise CLIError(f"--mode {args.mode!r}: give 'FREQUENCY,DAMPING' (Hz, ratio).")
        mode = tuple(values)
    try:
        return SimulatedPlant(jh.Model(parameters_arg(args.plant), model.actuator,
                                       model.variant, model.substeps),
                              reference, noise=args.noise or 0.0, delay=args.delay or 0,
                              mode=mode, seed=args.seed)
    except ValueError as err:
        raise CLIError(f"--plant: {err}") from None


def check_known_delay(delay: int | None, n_samples: int) -> None:
    """One line for a ``--known-delay`` of a period (``n_samples``) or more."""
    if delay is not None and delay >= n_samples:
        raise CLIError(f"--known-delay {delay}: a delay of a whole period or more "
                       f"({n_samples} samples) cannot be told from none; give the "
                       "acquisition's delay in samples, less than one period.")


def learn(args, model, reference, options):
    """The learning branch: one step from --measured (and --state), or --iterations
    steps on --plant. Returns (learner, state, measured errors)."""
    import os

    import numpy as np

    from jaxhyst.control import IterativeLearning
    from jaxhyst.control.learning_state import state_from_dict
    from jaxhyst.io import read_json

    delay = "correct" if args.known_delay is None else args.known_delay
    check_known_delay(args.known_delay, reference.n_samples)
    if args.plant:  # (every input checked before the long work)
        plant = _plant(args, model, reference)
        learner = IterativeLearning.of(model, reference, gain=args.gain or 1.0, delay=delay,
                                       **options)
        state = learner.init()
        for _ in range(args.iterations):
            if stop_requested():
                break
            state = learner.step(state, plant.measure(state.input))
            note("learning", str(state.reports[-1]))
            if state.stopped:
                break
        return learner, state
    applied, measured = _measured(args, model, reference)
    state = None
    if args.state and os.path.exists(args.state):
        try:
            state = state_from_dict(read_json(args.state), reference.n_samples)
        except ValueError as err:
            raise CLIError(f"--state {args.state}: {err}") from None
        if state.stopped:
            raise CLIError(f"--state {args.state}: learning has stopped ({state.stopped}); "
                           "remove the file to start again.")
        if np.max(np.abs(state.input - applied)) > 1e-6 * max(np.ptp(applied), 1e-300):
            raise CLIError(f"--measured {args.measured}: its input is not the one --state "
                           f"{args.state} says to apply next; measure that input (or remove "
                           "the state file to start again from this run).")
    learner = IterativeLearning.of(model, reference, gain=args.gain or 1.0, delay=delay,
                                       **options)
    if state is None:
        state = learner.state_for(applied)
    try:
        state = learner.step(state, measured)
    except ValueError as err:
        raise CLIError(f"--measured {args.measured}: {err}") from None
    return learner, state
