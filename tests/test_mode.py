"""The two narrow interfaces of the estimator (core/mode.py, core/host.py): both estimator modes answer every hook
the Localiser calls, and the Localiser offers every member its parts use, so swapping the mode never needs an
isinstance or getattr probe."""

from taco_mav.core.host import Host
from taco_mav.core.localiser import Localiser, make_localiser
from taco_mav.core.mode import Mode
from taco_mav.core.paper import PaperMode
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.mode import PlusMode
from taco_mav.core.plus.params import PlusParams


def _members(protocol: type) -> set[str]:
    names = set(getattr(protocol, "__annotations__", {}))
    names |= {n for n, v in vars(protocol).items()
              if not n.startswith("_") and (callable(v) or isinstance(v, property))}
    return names


def test_both_modes_answer_every_hook() -> None:
    hooks = _members(Mode)
    assert {"predict", "plan_search", "add_fix", "gnss_apply", "takes_ground_motion"} <= hooks
    for params in (LocaliserParams(), LocaliserParams(plus=PlusParams())):
        mode = make_localiser(params, 0.0).mode
        missing = sorted(h for h in hooks if not hasattr(mode, h))
        assert not missing, (type(mode).__name__, missing)
    assert PaperMode.takes_ground_motion is False and PlusMode.takes_ground_motion is True
    assert PaperMode.gnss_replaces is True and PlusMode.gnss_replaces is False


def test_the_localiser_offers_what_its_parts_use() -> None:
    loc = make_localiser(LocaliserParams(plus=PlusParams()), 0.0)
    members = _members(Host)
    assert {"ukf", "pre", "history", "take_pending", "fuse", "gnss"} <= members
    missing = sorted(m for m in members if not hasattr(loc, m))
    assert not missing, missing
    assert isinstance(loc, Localiser) and loc.gnss.guard is None and loc.gnss.in_use is False


def test_the_mode_follows_the_parameters_and_answers_the_same_calls() -> None:
    """Paper mode ignores what only taco+ uses (the camera's speed, the drive command) and keeps no lock; taco+
    uses the camera's speed."""
    paper = make_localiser(LocaliserParams(), 0.0)
    plus = make_localiser(LocaliserParams(plus=PlusParams()), 0.0)
    assert isinstance(paper.mode, PaperMode) and isinstance(plus.mode, PlusMode)
    assert paper.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "ignored" and not paper.takes_ground_motion
    paper.set_drive_command(0.0, True)
    assert paper.lock_events == [] and paper.take_lock_events() == []
    # before any frame, taco+ has no history to place the measurement in
    assert plus.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "stale" and plus.takes_ground_motion
