"""Figures read well: no legend covers data, and a residual panel shows the channel's
quantisation step as what it is (the staircase of a quantised reading lies inside it)."""
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from labrig.analysis import analyse  # noqa: E402
from labrig.diagnosis.evidence.evaluation import evaluate  # noqa: E402
from labrig.model.model import Model  # noqa: E402
from labrig.model.servo import ServoParams  # noqa: E402
from labrig.io.runs import read_dataset  # noqa: E402
from conftest import make_rig, sim_dataset, square_plan  # noqa: E402


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    rig = make_rig(effects={"deadband": {"d_v": 0.3}})
    ds = sim_dataset(tmp_path_factory.mktemp("fig"), rig, square_plan(amps=(1.0, 2.0), periods=1),
                     seed=3)
    runs = read_dataset([ds])
    # the linear model of the true plant: the dead zone shows as a large residual
    model = Model(params=ServoParams.from_rig(rig).plant_dict(), constants=dict(runs[0].constants))
    return rig, ds, runs, evaluate(runs, model)


def _overlaps(fig):
    """(legend, axes) pairs whose boxes overlap by more than a pixel."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    legends = [a.get_legend() for a in fig.axes if a.get_legend()] + list(fig.legends)
    out = []
    for leg in legends:
        lb = leg.get_window_extent(r)
        for ax in fig.axes:
            ab = ax.get_window_extent(r)
            w = min(lb.x1, ab.x1) - max(lb.x0, ab.x0)
            h = min(lb.y1, ab.y1) - max(lb.y0, ab.y0)
            if w > 1 and h > 1:
                out.append((leg.get_texts()[0].get_text(), ax.get_ylabel() or ax.get_title()))
    return out


def _figures(rig, ds, runs, ev):
    from labrig.analysis.plots import analysis_figures
    from labrig.diagnosis.results.plots import plot_ladder, plot_run_comparison
    from labrig.identification.plots import plot_convergence
    from labrig.analysis.run_plots import plot_overview

    for rr in ev.per_run:
        yield f"compare_{rr['name']}", plot_run_comparison(rr)
    for name, fig in analysis_figures(analyse([ds])).items():
        yield name, fig
    yield "overview", plot_overview(runs)
    steps = [{"label": lab, "rmse_over_noise": {"overall": e, "speed": e, "position": e},
              "cross_validated": e * 1.1} for lab, e in (("linear model", 9.0), ("+ deadband", 1.0))]
    yield "ladder", plot_ladder(steps)
    fits = [SimpleNamespace(method=m, fitness=f, result=SimpleNamespace(history=list(h)))
            for m, f, h in (("jfo", 1.2, np.geomspace(50, 1.2, 40)), ("co", 1.1, [0.1, 0.1]))]
    yield "convergence", plot_convergence(fits)


def test_no_legend_covers_an_axes(data):
    for name, fig in _figures(*data):
        try:
            assert _overlaps(fig) == [], name
        finally:
            plt.close(fig)


def test_residual_panel_shows_the_quantum_and_the_staircase_lies_inside_it(data):
    from labrig.diagnosis.results.plots import plot_run_comparison

    rig, _, runs, ev = data
    # the tacho's and the pot's ADC step in their channels' units
    q = {"speed": rig.bridge.adc_quantum_v / rig.sensors.tacho_v_per_rad_s,
         "position": rig.bridge.adc_quantum_v / rig.sensors.pos_v_per_rad}
    rr = ev.per_run[0]
    for ch, c in rr["channels"].items():
        assert c["quantum"] == pytest.approx(q[ch], rel=1e-4), ch  # read off the CSV
        assert c["quantum_kind"] == "ADC step"
        qn = c["quantum"] / c["sigma"]
        assert 1.0 < qn < 5.0  # the step is larger than the noise floor: a staircase shows
        # at rest before the first edge the model is exact: what is left is the
        # reading's staircase, one step either side of the truth and no more (the step
        # read off the data is a few ppm short of the CSV's levels: 0.1 % slack)
        k = int(np.argmax(rr["labels"] != "rest"))
        r = c["residual"][:k]
        assert k > 100 and np.mean(np.abs(r) <= 1.001 * qn) >= 0.95, ch
        assert np.mean(np.abs(r) > 0.5 * qn) > 0.05, ch  # the staircase does show
    fig = plot_run_comparison(rr)
    try:
        for ch, ax in zip(rr["channels"], fig.axes[1:4:2]):
            qn = rr["channels"][ch]["quantum"] / rr["channels"][ch]["sigma"]
            lines = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
            assert sorted(round(ln.get_ydata()[0], 9) for ln in lines) == [round(-qn, 9),
                                                                          round(qn, 9)]
            labels = [t.get_text() for t in ax.get_legend().get_texts()]
            assert any(t.startswith("+-1 quantum (ADC step ") for t in labels), labels
    finally:
        plt.close(fig)


def test_a_draft_figure_is_small_and_skips_the_layout(data, tmp_path, monkeypatch):
    """LABRIG_FIGURES=draft (the sheets' runs in the suite): the same figure saved at 40 dpi
    without tight_layout's measuring; the full figure is laid out (its axes moved) and
    saved at 110 dpi."""
    from labrig.analysis.run_plots import plot_overview
    from labrig.core import figures

    _, _, runs, _ = data
    sizes = {}
    for mode in ("", "draft"):
        monkeypatch.setenv("LABRIG_FIGURES", mode)
        fig = plot_overview(runs)
        box = fig.axes[0].get_position().bounds
        path = figures.save(fig, tmp_path / f"run{mode}.png")
        sizes[mode] = (plt.imread(path).shape[:2], box)
    (h_full, w_full), box_full = sizes[""]
    (h_draft, w_draft), box_draft = sizes["draft"]
    assert w_draft == pytest.approx(w_full * 40 / 110, abs=2)
    assert h_draft == pytest.approx(h_full * 40 / 110, abs=2)
    assert box_draft != box_full   # tight_layout moved the full figure's axes, not the draft's
