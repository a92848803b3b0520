"""The Model object, the EffectSet and the effects' own kernel mapping."""
from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

from labrig.core.errors import UserError
from labrig.model import simulate
from labrig.model.effects import CATALOGUE, Effect, FrictionEffect, InputEffect, Param, get_effect
from labrig.model.effectset import EffectSet
from labrig.model.model import Model
from labrig.io.runs import read_dataset

from conftest import make_rig, sim_dataset, square_plan

PLANT = {"R": 8.0, "L": 0.0085, "J": 5.2245e-5, "B": 1e-5, "K": 0.05}
CONST = {"Ka": 5.0, "N": 30.0, "Kt": 0.026, "Kpot": 0.5, "kp": 2.0, "kv": 0.15}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    plan = square_plan(amps=(1.2, 2.0), rate=500.0, periods=1)
    d = sim_dataset(tmp_path_factory.mktemp("m"), make_rig(effects={"deadband": {"d_v": 0.3}}),
                    plan, seed=3)
    return read_dataset(d)


def test_effectset_orders_names_and_refuses_two_frictions():
    es = EffectSet.parse("delay,deadband,offset")
    assert es.names == ["offset", "deadband", "delay"]          # input order, then the rest
    assert es.keys() == ["offset.u0_v", "deadband.d_v", "delay.td_s"]
    flat = {"offset.u0_v": 0.1, "deadband.d_v": 0.3, "delay.td_s": 0.01, "R": 8.0}
    nested = es.nest(flat)
    assert nested == {"offset": {"u0_v": 0.1}, "deadband": {"d_v": 0.3}, "delay": {"td_s": 0.01}}
    assert EffectSet.flatten(nested) == {k: v for k, v in flat.items() if "." in k}
    with pytest.raises(UserError, match="both act as friction"):
        EffectSet.parse("coulomb_friction,stiction")
    with pytest.raises(UserError, match="given twice"):
        EffectSet.parse("deadband,deadband")
    assert (es + [get_effect("backlash")]).names == ["offset", "deadband", "delay", "backlash"]


def test_model_round_trips_through_json_and_flat(tmp_path):
    m = Model(PLANT, EffectSet.parse("deadband,delay"),
              {"deadband": {"d_v": 0.3}, "delay": {"td_s": 0.004}}, CONST,
              info={"method": "co", "fitness": 1.2})
    path = m.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["format"] == "labrig-model/1" and doc["structure"] == "voltage"
    assert doc["effects"] == ["deadband", "delay"] and doc["fitness"] == 1.2
    back = Model.load(path)
    assert back.flat() == m.flat() and back.constants == CONST and back.names == m.names
    again = Model.from_flat(m.flat(), m.effects, CONST)
    assert again.effect_params == m.effect_params and again.params == m.params


def test_every_builtin_effect_maps_itself_onto_the_kernel():
    """The simulator never switches on an effect's name: each built-in effect says where it
    lives in the kernel, and writing it sets exactly that column."""
    src = inspect.getsource(simulate)
    for name in CATALOGUE:
        assert f'"{name}"' not in src, f"simulate.py names the effect {name}"
    plant_view = simulate._PlantView(np.array([8.0]), np.array([0.05]), 5.0)
    for name, cls in CATALOGUE.items():
        eff = cls()
        prm = np.zeros((1, simulate.N_COLS))
        p = {q.name: np.array([q.upper]) for q in eff.params}
        if name == "input_curve":   # a curve: the general path, as a user's input map
            assert not eff.to_kernel(simulate._KernelTable(prm), p, plant_view)
            continue
        assert eff.to_kernel(simulate._KernelTable(prm), p, plant_view), name
        assert np.count_nonzero(prm) >= 1, name


def test_user_effects_of_both_interfaces_run_on_the_general_path(runs):
    """A stage subclass and the small 'Effect with stage set' interface both simulate,
    and a user's dead zone equals the catalogue's."""
    class MyDeadband(InputEffect):
        name = "my_deadband"
        params = (Param("d_v", "V", 1e-3, 2.0, "dead zone"),)

        def apply(self, v, d_v):
            return np.sign(v) * np.maximum(np.abs(v) - d_v, 0.0)

    class PlainCoulomb(Effect):  # the first exercise sheets' interface
        name = "plain_coulomb"
        stage = "friction"
        params = (Param("tc_v", "V", 1e-3, 2.0, "friction"),)

        def friction(self, plant, tc_v):
            t = tc_v * plant.Ka * plant.K / plant.R
            return t, t

    mine = Model(PLANT, EffectSet([MyDeadband()]), {"my_deadband": {"d_v": 0.3}}, CONST)
    ours = Model(PLANT, EffectSet.parse("deadband"), {"deadband": {"d_v": 0.3}}, CONST)
    a, b = mine.simulate(runs), ours.simulate(runs)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x["w"], y["w"], rtol=0, atol=1e-9)
    plain = Model(PLANT, EffectSet([PlainCoulomb()]), {"plain_coulomb": {"tc_v": 0.25}}, CONST)
    cat = Model(PLANT, EffectSet.parse("coulomb_friction"),
                {"coulomb_friction": {"tc_v": 0.25}}, CONST)
    for x, y in zip(plain.simulate(runs), cat.simulate(runs)):
        np.testing.assert_allclose(x["w"], y["w"], rtol=0, atol=1e-9)
    assert isinstance(get_effect("coulomb_friction"), FrictionEffect)


def test_a_stage_class_without_its_hook_cannot_be_made():
    class Broken(FrictionEffect):
        name = "broken"

    with pytest.raises(TypeError):
        Broken()


def test_results_are_tabular_and_plottable(runs):
    """Evaluation, Diagnosis and Ladder give pandas tables, rich tables and figures."""
    import matplotlib.pyplot as plt

    from labrig.diagnosis.evidence.evaluation import evaluate
    from labrig.diagnosis.results.ladder import Ladder, LadderStep

    m = Model(PLANT, EffectSet.parse("deadband"), {"deadband": {"d_v": 0.3}}, CONST)
    ev = evaluate(runs, m)
    df = ev.to_pandas()
    assert set(df["run"]) == {r.name for r in runs} and (df["rmse_over_noise"] > 0).all()
    assert [row[0] for row in ev.table_rows().rows] == [r.name for r in runs]
    lad = Ladder([LadderStep.of("+ deadband", m, ev)])
    assert lad.to_pandas().shape[0] == 1 and "rmse/noise overall" in lad.to_pandas()
    fig = lad.plot()
    assert fig.axes and ev.plot().axes
    plt.close("all")
