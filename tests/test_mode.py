"""The estimator a Localiser composes (core/mode.py): both modes answer every member of `Estimator`, only taco+
has `Aids`, and the Localiser's public surface stays what its callers use."""

import inspect

from taco_mav.core.localiser import Localiser, make_localiser
from taco_mav.core.mode import Aids, Estimator
from taco_mav.core.paper import PaperMode
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.mode import PlusMode
from taco_mav.core.plus.params import PlusParams


def _members(protocol: type) -> set[str]:
    names = set(getattr(protocol, "__annotations__", {}))
    for klass in protocol.__mro__:
        if klass.__name__ in ("Protocol", "Generic", "object"):
            continue
        names |= {n for n, v in vars(klass).items() if not n.startswith("_") and callable(v)}
    return names


def test_both_modes_answer_every_member_and_only_taco_plus_has_aids() -> None:
    members = _members(Estimator)
    assert {"predict", "plan_search", "judge", "apply", "gnss_fused", "report", "aids"} <= members
    for params in (LocaliserParams(), LocaliserParams(plus=PlusParams())):
        est = make_localiser(params, 0.0).estimator
        missing = sorted(h for h in members if not hasattr(est, h))
        assert not missing, (type(est).__name__, missing)
    assert PaperMode.gnss_replaces is True and PlusMode.gnss_replaces is False
    plus = make_localiser(LocaliserParams(plus=PlusParams()), 0.0).estimator
    assert plus.aids is not None and not sorted(m for m in _members(Aids) if not hasattr(plus.aids, m))
    assert make_localiser(LocaliserParams(), 0.0).estimator.aids is None


def test_paper_mode_has_no_hook_that_does_nothing() -> None:
    """Every method of PaperMode has a body beyond its docstring (no `pass` hooks)."""
    for name, fn in vars(PaperMode).items():
        if callable(fn) and not name.startswith("__"):
            body = [ln.strip() for ln in inspect.getsource(fn).splitlines()[1:]]
            code = [ln for ln in body if ln and not ln.startswith(("#", '"""')) and ln != "pass"]
            assert code, name


def test_the_localisers_public_surface_is_a_dozen_methods() -> None:
    public = sorted(n for n, v in vars(Localiser).items()
                    if not n.startswith("_") and (callable(v) or isinstance(v, property)))
    assert len(public) <= 12, public
    assert {"add_imu", "poll_query", "add_fix", "add_gnss", "estimate"} <= set(public)


def test_the_estimator_follows_the_parameters_and_answers_the_same_calls() -> None:
    """Paper mode ignores what only taco+ uses (the camera's speed, the drive command) and keeps no lock; taco+
    uses the camera's speed."""
    paper = make_localiser(LocaliserParams(), 0.0)
    plus = make_localiser(LocaliserParams(plus=PlusParams()), 0.0)
    assert isinstance(paper.estimator, PaperMode) and isinstance(plus.estimator, PlusMode)
    assert paper.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "ignored" and not paper.takes_ground_motion
    paper.set_drive_command(0.0, True)
    assert paper.record.lock_events == [] and paper.take_lock_events() == []
    # before any frame, taco+ has no history to place the measurement in
    assert plus.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "stale" and plus.takes_ground_motion
    assert plus.gnss.guard is None and plus.gnss.in_use is False
