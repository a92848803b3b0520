"""The command line speaks with one voice: long messages are wrapped, never cut mid-word;
`diagnose -o` says what it saved; the ranking says what it is ordered by and when an
effect is supported; "separation" means one thing; `labrig --help` shows the order of
work; the options every command takes come last; identify and batch share defaults."""
from __future__ import annotations

import argparse
import json
import re
from types import SimpleNamespace

import pytest

from conftest import ROOT, labrig

DATA = ROOT / "data" / "sweep_default"
DIFFERENCE = "predicted difference (sum of squared differences of the two predictions, " \
             "in noise units)"


def _words(text: str) -> list[str]:
    return text.split()


# -- 1. wrapped, never cut ---------------------------------------------------------------

LONG_VERDICT = ("Add deadband: A symmetric dead zone of the bridge and amplifier: a symmetric "
                "1.8 V band of input that moves nothing. Cross-validated: 10.04 -> 0.99 on "
                "held-out data, better in 4 of 4 folds. The held-out evidence is in the "
                "acceleration of the position (17.01 -> 1.05, 9 % of the time); see "
                "docs/physics.md, 'Writing your own effect'. " * 2)


def test_round_log_lines_are_wrapped_with_every_word_whole():
    from labrig.diagnosis.loop.moves import LOG_WIDTH, wrap_log

    msg = f"round 2: {LONG_VERDICT}"
    text = wrap_log(msg)
    lines = text.splitlines()
    assert len(lines) > 2
    assert _words(text) == _words(msg)            # no word cut, dropped or added
    assert all(len(line) <= LOG_WIDTH for line in lines), text
    assert lines[0].startswith("round 2: ")
    assert all(line.startswith(" " * len("round 2: ")) for line in lines[1:])  # hanging
    # a move's message keeps its own indent and hangs four further
    move = wrap_log("  swap deadband -> stiction: " + LONG_VERDICT)
    assert _words(move) == _words("swap deadband -> stiction: " + LONG_VERDICT)
    assert all(line.startswith("      ") for line in move.splitlines()[1:])


def test_the_search_logs_the_whole_verdict(monkeypatch):
    """search() hands the round's whole verdict to the log (no slice of it)."""
    import labrig.diagnosis.loop.search as search

    said = []

    class Stop(Exception):
        pass

    diag = SimpleNamespace(verdict=LONG_VERDICT, recommendation=None, ranking=[],
                           base=SimpleNamespace(names=[]), evaluation=None,
                           cv_baseline=SimpleNamespace(rmse=1.0))
    monkeypatch.setattr(search, "diagnose", lambda *a, **k: diag)
    monkeypatch.setattr(search, "_Judge", lambda *a, **k: None)
    monkeypatch.setattr(search.LadderStep, "of", staticmethod(lambda *a, **k: None))

    def pair(*a, **k):
        raise Stop

    monkeypatch.setattr(search, "_pair", pair)
    with pytest.raises(Stop):
        search.search([], None, max_rounds=3, seed=0, log=said.append)
    assert len(said) == 1 and _words(said[0]) == _words(f"round 1: {LONG_VERDICT}")


def test_progress_log_wraps_long_lines(capsys):
    from labrig.commands.progress import LOG_WIDTH, Progress

    with Progress("test", total=None) as bar:
        bar.log("  " + LONG_VERDICT)
        bar.log("short line")
    err = capsys.readouterr().err
    assert _words(err) == _words(LONG_VERDICT + " short line")
    assert all(len(line) <= LOG_WIDTH for line in err.splitlines()), err


@pytest.mark.slow
def test_auto_round_summaries_end_on_whole_words():
    """The round summary on stderr is the round's verdict (--json), every word whole."""
    proc = labrig("diagnose", DATA, "--auto", "--max-rounds", "1", "--seed", "0", "--json",
                  check=0, cwd=ROOT)
    verdict = json.loads(proc.stdout)["rounds"][0]["verdict"]
    lines = proc.stderr.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("round 1: "))
    block = [lines[start]]
    for line in lines[start + 1:]:
        if not line.startswith(" " * len("round 1: ")):
            break
        block.append(line)
    assert _words(" ".join(block)) == _words(f"round 1: {verdict}"), proc.stderr
    assert all(len(line) <= 100 for line in block), proc.stderr


# -- 2. diagnose -o says what it saved ---------------------------------------------------

@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """`diagnose -o` with a recommendation (coulomb_friction) and without one (offset on
    the model that already has it)."""
    tmp = tmp_path_factory.mktemp("saved")
    m1, m2 = tmp / "m1.json", tmp / "m2.json"
    with_rec = labrig("diagnose", DATA, "--candidates", "coulomb_friction", "--seed", "0",
                      "-o", m1, check=0, cwd=ROOT)
    without = labrig("diagnose", DATA, "--model", m1, "--candidates", "offset", "--seed", "0",
                     "-o", m2, check=0, cwd=ROOT)
    as_json = labrig("diagnose", DATA, "--model", m1, "--candidates", "offset", "--seed", "0",
                     "-o", m2, "--json", check=0, cwd=ROOT)
    return SimpleNamespace(m1=m1, m2=m2, with_rec=with_rec, without=without, as_json=as_json)


def test_diagnose_o_says_where_it_saved_the_model(saved):
    assert saved.m1.is_file()
    assert "recommendation: coulomb_friction" in saved.with_rec.stdout
    assert f"model saved to {saved.m1}" in saved.with_rec.stdout


def test_diagnose_o_says_plainly_when_it_saved_nothing(saved):
    out = saved.without.stdout
    assert "recommendation: none" in out
    assert not saved.m2.exists()
    assert f"nothing saved to {saved.m2}" in out and "no recommendation" in out
    assert "model saved to" not in out
    # with --json, stdout stays one JSON object and the word goes to stderr
    doc = json.loads(saved.as_json.stdout)
    assert doc["recommendation"] is None
    assert f"nothing saved to {saved.m2}" in saved.as_json.stderr


# -- 3. the ranking says its order and its rule ------------------------------------------

def _diagnosis():
    from labrig.diagnosis.results.diagnosis import Candidate, Diagnosis

    cv = {"baseline": 10.0, "with_effect": 9.9, "improvement": 0.01, "folds_improved": 2,
          "folds": 4, "evidence": []}
    ranking = [Candidate("coulomb_friction", 1.0, 0.8, -2000.0, {"tc_v": 0.1}, {},
                         cross_validated=dict(cv, with_effect=1.0, improvement=0.9,
                                              folds_improved=4), supported=True),
               Candidate("delay", 5.0, 0.3, -500.0, {"td_s": 1e-3}, {}, cross_validated=cv,
                         supported=False, at_bound=["delay.td_s at the upper bound"]),
               Candidate("offset", 7.9, 0.01, -3.0, {"u0_v": 0.0}, {})]
    return Diagnosis(baseline={"source": "test", "effects": [],
                               "rmse_over_noise": {"overall": 8.0}},
                     regimes={"by_regime": {}, "by_amplitude": {}}, ranking=ranking,
                     recommendation="coulomb_friction", verdict="Add coulomb_friction.",
                     cross_validation={"kind": "whole runs held out in turn", "folds": 4},
                     criteria={"min_improvement": 0.05, "max_delta_bic": -10.0, "floor": 1.15},
                     seconds=0.0)


def test_the_ranking_notes_state_the_numbers_diagnose_uses():
    """The ranking's notes and the diagnosis read one set of criteria
    (labrig.diagnosis.evidence.criteria)."""
    from labrig.diagnosis.evidence import criteria
    from labrig.diagnosis.loop import diagnose
    from labrig.diagnosis.results import diagnosis as ranking
    from labrig.model.effects import get_effect

    assert ranking.PARSIMONY == diagnose.PARSIMONY
    assert ranking.CV_CANDIDATES == diagnose.CV_CANDIDATES
    assert ranking.SWAP_GAIN == diagnose.SWAP_GAIN
    assert ranking.SIMPLER_MARGIN == diagnose.SIMPLER_MARGIN
    # the order the note states is _score's: cross-validated error, raised per parameter
    # the move adds beyond the first (adding stiction adds two: tc_v and excess), lowered
    # per parameter a removal takes away
    n = len(get_effect("stiction").params)
    cand = ranking.Candidate("stiction", 1.0, 0.5, -100.0, {}, {}, extra_params=n,
                             cross_validated={"with_effect": 2.0})
    assert n >= 2
    assert criteria.score(cand) == pytest.approx(2.0 * (1 + ranking.PARSIMONY * (n - 1)))
    gone = ranking.Candidate("stiction", 1.0, 0.5, -100.0, {}, {}, move="remove",
                             extra_params=-n, cross_validated={"with_effect": 2.0})
    assert criteria.score(gone) == pytest.approx(2.0 * (1 - ranking.PARSIMONY * (n + 1)))


def test_the_ranking_table_says_what_it_is_ordered_by_and_when_supported():
    from labrig.diagnosis.loop.diagnose import CV_CANDIDATES, PARSIMONY

    notes = " ".join(_diagnosis().table_rows()[1].notes)
    assert "ordered by: the cross-validated rmse/noise" in notes
    assert f"{100 * PARSIMONY:g} % per parameter" in notes
    assert "not cross-validated come last, by dBIC" in notes
    assert "dBIC below -10" in notes and "gain of at least 5 %" in notes
    assert "cross-validated error falls by at least 5 %" in notes
    assert "more than half of the counted folds improved" in notes
    assert "'- X' removes X" in notes and "'X -> Y' replaces X by Y" in notes
    assert "3 standard errors" in notes
    assert "a strongly negative dBIC alone is not enough" in notes
    assert f"only the {CV_CANDIDATES} largest gains" in notes
    assert "simpler, fits within 2 %" in notes
    assert "(at bound)" in notes and "does not enter the decision" in notes


def test_the_ranking_notes_read_without_criteria():
    """A diagnosis.json without its criteria (the report reads them as None)."""
    from dataclasses import replace

    d = replace(_diagnosis(), criteria={"min_improvement": None, "max_delta_bic": None})
    notes = " ".join(d.table_rows()[1].notes)
    assert "dBIC below the BIC threshold" in notes and "at least the minimum gain" in notes


def test_the_ranking_json_keys_are_unchanged():
    d = _diagnosis().to_json()
    # (the keys, not their order: a JSON object has none)
    assert sorted(d) == sorted(["baseline", "regimes", "ranking", "recommendation", "verdict",
                                "cross_validation", "noise", "weights", "criteria", "seconds"])
    # "move" and "label" say whether the row adds, removes or replaces; "replaces" and
    # "unresolved" appear only on the rows they describe
    assert sorted(d["ranking"][0]) == sorted(["effect", "move", "label", "rmse_over_noise",
                                              "improvement", "delta_bic", "params",
                                              "fit_percent", "cross_validated", "at_bound",
                                              "supported", "explanation"])


def test_the_cli_ranking_carries_the_notes(saved):
    out = saved.with_rec.stdout
    assert "ordered by:" in out and "a strongly negative dBIC alone is not enough" in out


# -- 4. one "separation" -----------------------------------------------------------------

def test_separation_is_the_decisions_ratio_and_a_proposal_predicts_that_one():
    """A proposal's "separation" is the decision's measure (worse rmse/noise over better,
    minus one), said with its definition wherever it appears; its sum of squares is the
    "predicted difference"."""
    from labrig.design.decide import Decision
    from labrig.design.inputs import InputCandidate as Input
    from labrig.design.proposal import SEPARATION, Hypothesis, Judged, Proposal

    model = SimpleNamespace(describe=lambda: "a model")
    inp = Input("ramp", [[0.0, 0.0], [5.0, 1.2], [10.0, -1.2]], "ramp through zero +-1.2 V")
    chosen = Judged(inp, naive=900.0, robust=400.0,
                    refit={"deadband": 1.3, "coulomb_friction": 2.1})
    prop = Proposal(pair=("deadband", "coulomb_friction"),
                    hypotheses=[Hypothesis("deadband", model, 1.0),
                                Hypothesis("coulomb_friction", model, 1.1)],
                    judged=[chosen], chosen=chosen, sigmas={}, template=SimpleNamespace(fs=200.0),
                    budget_s=20.0, amax=2.5, plausible=[1, 1])
    assert SEPARATION == "worse rmse/noise over better, minus one"
    text = prop.to_text()
    comments = [line for line in prop.to_toml().splitlines() if line.startswith("#")]
    notes = [n for t in prop.table_rows() for n in t.notes]
    for said in (text, "\n".join(comments), "\n".join(notes)):
        for line in said.splitlines():
            if "separation" in line.lower() and not line.startswith("  input "):
                # never without what it means (the table's column: defined above it)
                assert f"separation ({SEPARATION})" in line.lower(), line
    assert DIFFERENCE in text and "1.30 with deadband true" in text
    assert any(DIFFERENCE.capitalize() in line for line in comments), comments
    assert any("predicted difference (sum of squared differences of the two predictions, in "
               "noise units)" in n for n in notes)
    assert set(prop.to_json()["proposed"]["separation"]) == {"naive", "after_refit",
                                                              "worst_after_refit"}
    assert prop.to_json()["proposed"]["separation"]["worst_after_refit"] == 1.3

    d = Decision(("deadband", "coulomb_friction"), {"deadband": 1.0, "coulomb_friction": 1.05},
                 {"deadband": 1.0, "coulomb_friction": 2.0}, ["proposed"])
    assert "separation 0.050 before, 1.000 after (worse rmse/noise over better, minus one" \
        in d.to_text()
    assert "separation (worse rmse/noise over better, minus one)" in d.table_rows().notes[0]
    assert {"separation_before", "separation_after"} <= set(d.to_json())


# -- 5. labrig --help shows the order of work --------------------------------------------

def test_help_shows_the_order_of_work():
    proc = labrig("--help", check=0, cwd=ROOT)
    out = proc.stdout
    assert "sweep/import -> analyse -> identify -> diagnose -> propose" in out
    steps = [re.search(rf"^\s+{n}\.\s+(\S+)", out, re.M) for n in range(1, 6)]
    assert [m.group(1) for m in steps] == ["sweep", "analyse", "identify", "diagnose",
                                           "propose"], out
    assert "labrig COMMAND --help" in out


# -- 6. the options every command takes come last ----------------------------------------

def test_trust_code_is_the_last_option_of_every_command():
    from labrig.cli import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(subs.choices) >= 10
    for name, sp in subs.choices.items():
        options = [a for a in sp._actions if a.option_strings]
        assert options[-1].option_strings == ["--trust-code"], name
        assert "--debug" in [s for a in options for s in a.option_strings], name
        lines = [line for line in sp.format_help().splitlines() if line.startswith("  -")]
        assert lines[-1].startswith("  --trust-code FILE.py"), (name, lines[-3:])


def test_trust_code_is_last_in_the_printed_help():
    out = labrig("identify", "--help", check=0, cwd=ROOT).stdout
    assert out.rindex("--trust-code FILE.py") > out.rindex("--figures") > 0


# -- 7. identify and batch share the defaults --------------------------------------------

def test_identify_and_batch_default_to_the_same_method(monkeypatch):
    from labrig.cli import build_parser
    from labrig.classroom.batch import Identify
    from labrig.core.defaults import METHOD
    import labrig.identification.engine as engine

    parser = build_parser()
    assert parser.parse_args(["identify", "d"]).method == METHOD
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {name: {a.dest: a.help for a in sp._actions}
             for name, sp in subs.choices.items()}
    assert f"default {METHOD};" in helps["identify"]["method"]
    assert f"default {METHOD}," in helps["batch"]["method"]
    assert "jfo)" not in helps["batch"]["method"]

    # a batch identify task without --method fits with METHOD
    class Picked(Exception):
        pass

    def identify(runs, method, *a, **k):
        raise Picked(method)

    monkeypatch.setattr(engine, "identify", identify)
    with pytest.raises(Picked) as got:
        Identify().run(DATA, {"seed": 1})
    assert got.value.args[0] == METHOD
