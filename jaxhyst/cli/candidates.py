"""Which candidates ``identify --joint --leave-one-out`` compares: the forms --variant
names (a form, its own loss coefficients ``form+loss+…``, its own condition law
``form@law``), or the documented ones chosen from the loops; the spec entries of each,
and the one-line errors a comparison gets before any work (`jaxhyst.cli.heldout` runs it).
"""

from __future__ import annotations

from .spec import CLIError

#: The documented candidates compared when no form is named.
CANDIDATES = ("classic", "energy", "play", "preisach")
#: … and where the loops span frequencies (`spans_frequencies`, times given, no loss
#: coefficient or law in the frequency named): two static forms and the two rate
#: mechanisms on the pinning cells — a static form draws every frequency alike.
RATE_CANDIDATES = ("play", "classic", "play+relax", "play+eddy+excess")
#: … and where three loops or more span amplitudes and no law is named: the pinning
#: cells' log-normal width as a power of the amplitude too (``form@law``: a candidate
#: with a condition law of its own, --vary's syntax).
AMPLITUDE_CANDIDATE = "play@spread:log_amplitude"


def spans_frequencies(loops, factor: float = 1.1) -> tuple[float, float] | None:
    """(lowest, highest) frequency where every loop carries one and they lie more than
    ``factor`` apart; else None."""
    f = [lp.conditions.get("frequency") for lp in loops]
    if len(loops) < 2 or any(v is None for v in f) or max(f) <= factor * min(f):
        return None
    return min(f), max(f)


def split_candidate(candidate: str) -> tuple[str, list[str], str]:
    """``form+loss+…@law`` → (form, its own loss coefficients, its law or '')."""
    body, _, law = candidate.partition("@")
    form, *losses = body.split("+")
    return form, losses, law


def singles_key(form: str) -> tuple:
    """What a candidate's loops alone are fitted with: its form and its loss coefficients,
    not its law (candidates differing only by a law share those fits)."""
    name, losses, _ = split_candidate(form)
    return name, tuple(losses)


def _spans_amplitudes(loops, by_B: bool = False, factor: float = 1.1) -> bool:
    """Three loops or more whose amplitudes lie more than ``factor`` apart without any
    one of them: every fold's training loops span amplitudes (a law in the amplitude
    needs two). The amplitude is the one the law reads (`problems.loop_conditions`): the
    peak drive |H| or |I|, or the peak flux density |B| where ``by_B`` (a B-driven fit)."""
    import numpy as np

    def peak(lp):
        x = lp.signals.get("B") if by_B else lp.H if lp.H is not None else lp.I
        return None if x is None else float(np.max(np.abs(x)))

    peaks = [p for p in map(peak, loops) if p is not None]
    if len(loops) < 3 or len(peaks) != len(loops):
        return False
    folds = [peaks[:i] + peaks[i + 1:] for i in range(len(peaks))]
    return all(max(p) > factor * min(p) for p in folds)


def _check_fold_laws(spec, loops, forms) -> None:
    """A one-line error where a fold's training loops cannot determine a compared
    candidate's condition law (`jaxhyst.ConditionModel.undetermined`): loops at one
    amplitude, say, fix no slope in it."""
    import jaxhyst as jh

    from .problems import loop_conditions, parse_vary

    laws = {f: {**parse_vary(spec.get("vary")), **parse_vary(split_candidate(f)[2])}
            for f in forms}
    laws = {f: law for f, law in laws.items() if law}
    if not laws:
        return
    actuator = jh.Actuator(**spec["actuator"])
    for i, held in enumerate(loops):
        train = loops[:i] + loops[i + 1:]
        c = loop_conditions(spec, train, actuator)
        for form, law in laws.items():
            why = jh.ConditionModel(law, int(spec.get("vary_degree", 1))).undetermined(c)
            if why:
                raise CLIError(f"--leave-one-out: the fold without loop {held.index} cannot "
                               f"fit the law of {form}: {why}")


def candidates(args, loops=None) -> list[str]:
    """The candidates --variant names (a list with --leave-one-out): a form, a form with
    loss coefficients of its own (``play+relax``), either with a condition law of its own
    (``play@spread:log_amplitude``). None named: the documented ones — `RATE_CANDIDATES`
    where ``loops`` (given once read) span frequencies, carry times and neither --losses
    nor a law in the frequency is given; else `CANDIDATES`, with `AMPLITUDE_CANDIDATE`
    where they span amplitudes and no --vary is given."""
    from .options import VARIANTS
    from .problems import LOSS_NAMES, parse_vary

    if args.variant is None:
        if not args.leave_one_out:
            return ["energy"]
        rated = loops is not None and spans_frequencies(loops) and \
            all(lp.t is not None for lp in loops) and not args.losses and \
            not any("log_f" in f for f in parse_vary(args.vary).values())
        lawful = loops is not None and not args.vary and \
            _spans_amplitudes(loops, getattr(args, "driven_by", "H") == "B")
        return list(RATE_CANDIDATES if rated else
                    CANDIDATES + ((AMPLITUDE_CANDIDATE,) if lawful else ()))
    forms = [f.strip() for f in args.variant.split(",") if f.strip()]
    for f in forms:
        form, losses, law = split_candidate(f)
        if form not in VARIANTS or any(n not in LOSS_NAMES for n in losses) or \
                len(set(losses)) != len(losses) or ("@" in f and not law.strip()):
            raise CLIError(f"--variant {args.variant!r}: the forms are "
                           f"{', '.join(VARIANTS)}, each optionally with loss coefficients "
                           f"of its own from {', '.join(LOSS_NAMES)} (e.g. play+relax) and "
                           "a condition law of its own (e.g. play@spread:log_amplitude).")
        if "@" in law:
            raise CLIError(f"--variant {f}: a candidate carries one condition law after "
                           "'@' (e.g. play@spread:log_amplitude); compare two laws as two "
                           "candidates.")
        if law and not args.joint:
            raise CLIError(f"--variant {f}: a condition law needs --joint (several loops "
                           "fitted together).")
        named = set(parse_vary(law))
        if len(named) > 1 or named & set(parse_vary(args.vary)) or (
                named & {"spread", "a_rev"} and form not in ("play", "preisach")):
            raise CLIError(f"--variant {f}: a candidate's law names one parameter of its form "
                           f"that --vary does not name (e.g. play@spread:log_amplitude).")
    twice = sorted({f for f in forms if forms.count(f) > 1})
    if twice:
        raise CLIError(f"--variant {args.variant}: {', '.join(twice)} named twice; name "
                       "each candidate once.")
    if not forms:
        raise CLIError(f"--variant {args.variant!r}: the forms are {', '.join(VARIANTS)}.")
    if len(forms) > 1 and not args.leave_one_out:
        raise CLIError(f"--variant {args.variant}: several forms are compared only by "
                       "--leave-one-out (with --joint); name one form to fit.")
    return forms


def loss_names(text) -> list[str]:
    """--losses 'eddy,excess,relax' → the loss coefficients to identify."""
    from .problems import LOSS_NAMES

    if not text:
        return []
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in LOSS_NAMES]
    if bad or not names or len(set(names)) != len(names):
        raise CLIError(f"--losses {text!r}: name the loss coefficients to identify, each "
                       f"once, from {list(LOSS_NAMES)}.")
    return names


def candidate_spec(args, candidate: str) -> dict:
    """The spec entries of a candidate of --variant: ``form``, ``form+loss+…`` and either
    with ``@law`` → its form, loss coefficients (--losses' and its own) and condition
    laws (--vary's and its own)."""
    form, own, law = split_candidate(candidate)
    given = loss_names(args.losses)
    return {"variant": form, "losses": [*given, *(n for n in own if n not in given)],
            "vary": ",".join(v for v in (args.vary, law) if v) or None}


def rate_note(spec, loops, candidates=()) -> str | None:
    """Where the loops were measured at frequencies more than 10 % apart and nothing in
    the model depends on the rate (no loss coefficients, no law in the frequency): what
    that means and the options that change it; else None."""
    from .problems import parse_vary

    span = spans_frequencies(loops)
    if span is None or spec.get("losses") or \
            any(split_candidate(c)[1] for c in candidates) or \
            any("log_f" in feats for feats in parse_vary(spec.get("vary")).values()):
        return None
    lo, hi = span
    needs = "" if all(lp.t is not None for lp in loops) else (
        " (the file needs times: a t column, or loops sampled uniformly from a sinusoid "
        "with their frequency)")
    return (f"the loops were measured at {lo:.4g}–{hi:.4g} Hz and the model is rate "
            "independent: it draws every frequency alike. --losses eddy,excess,lag,relax adds "
            f"the rate-dependent model{needs}, --variant play+eddy+excess,play+relax "
            "compares mechanisms; --vary P:log_f a law in the frequency")


def check_comparison(spec, loops, forms) -> None:
    """One-line errors before any work: too few loops for the folds, a condition law a
    compared form cannot carry."""
    from .problems import parse_vary

    L = len(loops)
    vary = parse_vary(spec.get("vary"))  # (--vary's: before a candidate's own law)
    lawful = bool(vary) or any("@" in f for f in forms)
    need = 2 + (int(spec.get("vary_degree", 1)) if lawful else 0)
    if L < need:
        what = (f"a condition law of degree {spec.get('vary_degree', 1)} needs "
                f"{need - 1} training loops in every fold" if lawful else
                "every fold needs a loop to fit and one to predict")
        raise CLIError(f"--leave-one-out: {spec['data']} holds {L} loop"
                       f"{'s' if L != 1 else ''}; {what}, so give at least {need} loops.")
    timed = [f for f in forms if split_candidate(f)[1]]
    untimed = [lp.index for lp in loops if lp.t is None]
    if timed and untimed:
        raise CLIError(f"--variant {timed[0]}: loss coefficients need times, and loop "
                       f"{untimed[0]} of {spec['data']} has no t column; compare forms "
                       "without them or give times.")
    own = [n for n in vary if n in ("spread", "a_rev")]
    plain = [f for f in forms if split_candidate(f)[0] not in ("play", "preisach")]
    if own and plain:
        raise CLIError(f"--vary {own[0]}: only the forms of pinning cells (play, preisach) "
                       f"have it, and the comparison includes {plain}; name the forms with "
                       "--variant play,preisach or vary another parameter.")
    _check_fold_laws(spec, loops, forms)
