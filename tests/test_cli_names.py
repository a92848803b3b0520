"""What a newcomer types: every option of every subcommand says what it does, and method
and effect names are taken in any case, on the command line and in the files labrig reads."""
import argparse
import re
import json
from pathlib import Path

import numpy as np
import pytest

from labrig.cli import build_parser, main
from conftest import ROOT, make_rig, sim_dataset, square_plan


def _options(parser, path=("labrig",)):
    """(command path, action) for every action of every (nested) subcommand, including
    any added later: the walk starts at the parser labrig itself builds."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, (*path, name))
        else:
            yield path, action


def test_every_option_of_every_subcommand_has_help():
    parser = build_parser()
    subcommands = {p[1] for p, _ in _options(parser) if len(p) > 1}
    assert {"sweep", "identify", "ladder", "import", "diagnose", "mystery"} <= subcommands
    bare = [f"{' '.join(p)} {'/'.join(a.option_strings) or a.dest}"
            for p, a in _options(parser) if not a.help or a.help == argparse.SUPPRESS]
    assert bare == []


def test_options_that_take_a_name_take_it_in_any_case():
    named = [(p, a) for p, a in _options(build_parser())
             if a.choices and all(isinstance(c, str) for c in a.choices)]
    assert len(named) >= 8  # --method, --through (x4), --rule, --drive, --axis, --loop, ...
    for p, a in named:
        for c in a.choices:
            assert a.type is not None and a.type(c.upper()) == c, (p, a.option_strings)
    args = build_parser().parse_args(["identify", "d", "--method", "JFO", "--through", "Loop"])
    assert (args.method, args.through) == ("jfo", "loop")


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    plan = square_plan(amps=(1.2, 2.0), rate=200.0, periods=1)
    return sim_dataset(tmp_path_factory.mktemp("names"), make_rig(effects={}), plan, seed=1)


def test_identify_takes_method_and_effect_names_in_any_case(ds, capsys):
    p = make_rig().plant
    rc = main(["identify", str(ds), "--method", "JFO", "--pop", "6", "--iters", "3", "--seed", "1",
               "--effects", "OFFSET", "--bounds", "Offset.U0_V=-0.2:0.2",
               "--fix", f"R={p.R},L={p.L},K={p.K},OFFSET.u0_v=0.05", "--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    d = json.loads(out)
    assert d["method"] == "jfo" and d["effects"] == ["offset"]
    assert d["effect_params"]["offset"]["u0_v"] == pytest.approx(0.05)
    assert "offset.u0_v" in d["fixed"]


def test_the_python_api_takes_a_method_in_any_case(ds):
    from labrig.identification.engine import identify
    from labrig.io.runs import read_dataset

    p = make_rig().plant
    res = identify(read_dataset([ds]), "PSO", pop=6, iters=2, seed=1, identifiability=False,
                   fixed={"R": p.R, "L": p.L, "K": p.K})
    assert res.method == "pso" and res.result.nfev >= 12


def test_files_name_effects_in_any_case(tmp_path):
    from labrig.io.experiment import Experiment
    from labrig.io.config import load_plan, load_rig
    from labrig.diagnosis.loop.diagnose import candidate_names
    from labrig.model.model import Model
    from labrig.design.pairs import default_pair
    from labrig.io.runs import read_dataset

    # a rig file: [effects.Deadband] is the dead zone, and the simulated rig plays it
    text = (ROOT / "configs" / "rig_default.toml").read_text()
    text = text.replace("[effects.coulomb_friction]\ntc_v = 0.13", "[effects.Deadband]\nd_v = 0.5")
    (tmp_path / "rig.toml").write_text(text)
    rig = load_rig(tmp_path / "rig.toml")
    assert rig.effects == {"deadband": {"d_v": 0.5}}
    plan = [Experiment(name="sq_0.40V", amplitude_v=0.4, frequency_hz=0.5, periods=1,
                       lead_in_s=0.2, sample_rate_hz=200.0)]
    run = read_dataset(sim_dataset(tmp_path, rig, plan, seed=1))[0]
    q = rig.bridge.adc_quantum_v / rig.sensors.tacho_v_per_rad_s
    assert np.max(np.abs(run.speed)) <= 3 * q  # 0.4 V never gets through a 0.5 V dead zone

    # a plan: between = ["Deadband", "COULOMB_FRICTION"]
    (tmp_path / "plan.toml").write_text(
        '[[experiment]]\nname = "p"\nwaveform = "step"\namplitude_v = 1.0\nduration_s = 1.0\n'
        'between = ["Deadband", "COULOMB_FRICTION"]\n')
    assert load_plan(tmp_path / "plan.toml")[0].between == ["deadband", "coulomb_friction"]

    # a model file written by hand
    doc = Model(params={"R": 8.0, "L": 8e-3, "J": 5e-5, "B": 1e-5, "K": 0.05},
                constants={"Ka": 4.0, "N": 30.0}).to_json()
    doc.update(effects=["Deadband"], effect_params={"Deadband": {"d_v": 0.3}})
    (tmp_path / "m.json").write_text(json.dumps(doc))
    m = Model.load(tmp_path / "m.json")
    assert m.names == ["deadband"] and m.effect_params == {"deadband": {"d_v": 0.3}}

    # diagnose --candidates and propose --between
    assert candidate_names(Model(params=m.params), ["OFFSET", "Delay"]) == ["offset", "delay"]
    assert default_pair(m, "Deadband, COULOMB_friction") == ("deadband", "coulomb_friction")


def test_mystery_check_finds_an_effect_named_in_another_case(tmp_path):
    from labrig.io.mystery import check, load_mystery

    mys = tmp_path / "lab.mystery"
    assert main(["mystery", "new", "--seed", "7", "-o", str(mys)]) == 0
    truth = load_mystery(mys)["rig"]
    name, params = next(iter(truth["effects"].items()))
    from labrig.model.model import FORMAT

    model = {"format": FORMAT, "params": {"R": 8.0, "L": 8e-3, "J": 5e-5, "B": 1e-5,
                                                    "K": 0.05},
             "effects": [name.upper()], "effect_params": {name.title(): dict(params)}}
    (tmp_path / "m.json").write_text(json.dumps(model))
    res = check(mys, tmp_path / "m.json")
    assert res["effects"][name]["status"] == "found" and res["effects"][name]["as"] == name


def test_plan_keywords_in_any_case(tmp_path):
    """A plan's loop and waveform are keywords like method names: any case is the same
    keyword, and a wrong one is still refused with the choices named."""
    from labrig.io.config import load_plan
    from labrig.core.errors import ConfigError

    p = tmp_path / "plan.toml"
    p.write_text('[[experiment]]\nloop = "Open"\nwaveform = "SQUARE"\namplitudes_v = [1.0]\n'
                 'frequency_hz = 0.25\nperiods = 1\n')
    (exp,) = load_plan(p)
    assert (exp.loop, exp.waveform) == ("open", "square")
    p.write_text(p.read_text().replace("SQUARE", "Sine"))
    with pytest.raises(ConfigError, match="'square', 'step'"):
        load_plan(p)


def test_the_seed_defaults_are_what_the_readme_says_and_no_help_quotes_a_time():
    """Every subcommand's --seed defaults to labrig's SEED (0) except the whole-lab
    commands demo, report and batch (1, the sheets' seed); sweep's is the rig file's and a
    mystery's is required (docs/project/validation.md, 'The same answer from the same files'). No help
    text quotes a duration: times are measured by the benchmarks, and a machine's differ."""
    from labrig.core.defaults import SEED

    seeds = {p: a for p, a in _options(build_parser()) if "--seed" in a.option_strings}
    assert SEED == 0
    for path, action in seeds.items():
        want = {"demo": 1, "report": 1, "batch": 1, "sweep": None}.get(path[1], SEED)
        if path[1] == "mystery":
            assert action.required, path
        else:
            assert action.default == want, (path, action.default)
    timed = [f"{' '.join(p)} {'/'.join(a.option_strings) or a.dest}: {a.help}"
             for p, a in _options(build_parser()) if a.help and
             re.search(r"\b\d+(\.\d+)? ?(s|min|seconds?|minutes?)\b|few minutes", a.help)]
    assert timed == []


def test_every_command_and_nested_command_takes_debug_and_trust_code():
    """`labrig --help` says every command takes --debug and --trust-code: so do the nested
    ones (class serve, mystery new), before or after the nested command's name."""
    leaves = {}
    for path, action in _options(build_parser()):
        leaves.setdefault(path, set()).update(action.option_strings)
    nested = [p for p in leaves if len(p) > 1 and not any(q[:len(p)] == p and q != p
                                                          for q in leaves)]
    assert ("labrig", "class", "serve") in nested and ("labrig", "mystery", "new") in nested
    for path in nested:
        assert {"--debug", "--trust-code"} <= leaves[path], path
    for argv in (["class", "serve", "none.toml", "--debug"], ["class", "--debug", "serve", "none.toml"]):
        args = build_parser().parse_args(argv)
        assert args.debug is True, argv
    assert build_parser().parse_args(["class", "serve", "none.toml"]).debug is False
