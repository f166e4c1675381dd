"""The estimator a Localiser composes (core/estimator.py): each mode's parts answer their protocols, the paper has
no reported-accuracy part and no aiding, no part has a hook that does nothing, and the Localiser's public surface
stays what its callers use."""

import inspect

import pytest

from taco_mav.core import estimator as est_mod
from taco_mav.core import paper
from taco_mav.core.localiser import Localiser, make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus import aiding, filter as plus_filter, fix_policy, gnss, report, trigger
from taco_mav.core.plus.params import PlusParams

PAPER, PLUS = LocaliserParams(), LocaliserParams(plus=PlusParams())
PROTOCOLS = {"filter": est_mod.FilterModel, "trigger": est_mod.Trigger, "fixes": est_mod.FixPolicy,
             "gnss": est_mod.GnssPolicy, "report": est_mod.Report, "aids": est_mod.Aids}


def _members(protocol: type) -> set[str]:
    names: set[str] = set()
    for klass in protocol.__mro__:
        if klass.__module__ in ("typing", "builtins"):
            continue
        names |= set(getattr(klass, "__annotations__", {}))
        names |= {n for n, v in vars(klass).items() if not n.startswith("_") and callable(v)}
    return names


@pytest.mark.parametrize("params", [PAPER, PLUS], ids=["paper", "taco+"])
def test_each_part_answers_its_protocol(params):
    parts = make_localiser(params, 0.0).estimator
    for field, protocol in PROTOCOLS.items():
        part = getattr(parts, field)
        if part is None:
            continue
        missing = sorted(m for m in _members(protocol) if not hasattr(part, m))
        assert not missing, (field, type(part).__name__, missing)


def test_the_paper_has_no_reported_accuracy_part_and_no_aiding():
    paper_parts = make_localiser(PAPER, 0.0).estimator
    plus_parts = make_localiser(PLUS, 0.0).estimator
    assert paper_parts.report is None and paper_parts.aids is None
    assert plus_parts.report is not None and plus_parts.aids is not None
    assert paper_parts.gnss.replaces is True and plus_parts.gnss.replaces is False


@pytest.mark.parametrize("module", [paper, plus_filter, trigger, fix_policy, gnss, report, aiding])
def test_no_part_has_a_hook_that_does_nothing(module):
    """Every method of every part class has code beyond its docstring (no `pass` hooks)."""
    for _, klass in inspect.getmembers(module, inspect.isclass):
        if klass.__module__ != module.__name__ or klass.__name__.startswith("_"):
            continue
        for name, fn in vars(klass).items():
            if inspect.isfunction(fn) and not (name.startswith("__") and name != "__init__"):
                lines = inspect.getsource(fn).splitlines()[1:]
                code, in_doc = [], False
                for ln in (x.strip() for x in lines):
                    if ln.startswith('"""'):
                        in_doc = not (in_doc or (ln.endswith('"""') and len(ln) > 3))
                        continue
                    if in_doc:
                        in_doc = not ln.endswith('"""')
                        continue
                    if ln and not ln.startswith("#") and ln != "pass":
                        code.append(ln)
                assert code, f"{klass.__name__}.{name}"


def test_the_localisers_public_surface_is_a_dozen_methods():
    public = sorted(n for n, v in vars(Localiser).items()
                    if not n.startswith("_") and (callable(v) or isinstance(v, property)))
    assert len(public) <= 12, public
    assert {"add_imu", "poll_query", "add_fix", "add_gnss", "estimate"} <= set(public)


def test_paper_mode_ignores_what_only_taco_plus_uses():
    """The camera's speed and the drive command are taco+'s; paper mode keeps no lock."""
    paper_loc, plus_loc = make_localiser(PAPER, 0.0), make_localiser(PLUS, 0.0)
    assert paper_loc.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "ignored" and not paper_loc.takes_ground_motion
    paper_loc.set_drive_command(0.0, True)
    assert paper_loc.record.lock_events == [] and paper_loc.take_lock_events() == []
    # before any frame, taco+ has no history to place the measurement in
    assert plus_loc.add_ground_motion(0.0, 0.2, 0.5, 0.0, 0.05) == "stale" and plus_loc.takes_ground_motion
    assert plus_loc.gnss.guard is None and plus_loc.gnss.in_use is False
