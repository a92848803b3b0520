"""The result of a fit: :class:`Identification`, an identified model and everything known
about how good it is (:func:`labrig.identification.engine.solve` makes it); its JSON is
the fit's record (:mod:`labrig.identification.doc`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from labrig.model import drive_units
from labrig.model.effects import Effect
from labrig.model.model import Model
from labrig.model.servo import ServoParams, step_info
from labrig.identification.objective import Space
from labrig.identification.result import IdentResult
from labrig.core.display import Displayable
from labrig.identification.table import comparison_table, identification_dict


@dataclass(repr=False)
class Identification(Displayable):
    """An identified model and everything known about how good it is.

    Attributes
    ----------
    method : str
        ``"co"``, ``"jfo"`` or ``"pso"``.
    effects : list of Effect
        The model's effects.
    params : dict
        Every fitted parameter, physical units (an effect's as ``"name.param"``).
    metrics : dict
        ``fitness``, rmse/noise and fit % per channel, the parameters at a bound.
    identifiable : dict
        Per parameter, its interval where the data resolve it, or why not.
    seconds : float
        Wall time of the fit.
    result : IdentResult
        The optimiser's own record: its ``seed`` (repeat the fit with it), evaluations,
        history and message.

    ``model()`` is the fitted :class:`~labrig.model.model.Model`; ``to_json()`` is
    ``labrig identify --json``.

    Examples
    --------
    >>> import labrig as lr
    >>> fit = lr.identify("data/sweep_default")  # doctest: +SKIP
    >>> round(fit.metrics["fitness"]), sorted(fit.model().params)  # doctest: +SKIP
    (8, ['B', 'J', 'K', 'L', 'R'])
    """

    method: str
    effects: list[Effect]
    space: Space
    params: dict                      # every parameter, physical units
    result: IdentResult
    metrics: dict
    identifiable: dict
    seconds: float
    constants: dict
    dataset: dict = field(default_factory=dict)
    #: live, not in the JSON: the runs it was fitted to (for the overlay figure)
    runs: list | None = field(default=None, compare=False)
    #: starts of the same fit that diverged (their simulation overflowed) and were dropped
    failed_starts: int = 0

    @property
    def diverged(self) -> bool:
        """The fit's simulation overflowed or went non-finite: no model to use."""
        return not np.isfinite(self.metrics.get("fitness", np.nan))

    @property
    def stopped(self) -> bool:
        """Every start of the fit was ended early by its ``stop`` rule (status -2): the
        model is where the fit stood then, not converged."""
        starts = (self.result.extra or {}).get("starts") or []
        return bool(starts) and all(st.get("status") == -2 for st in starts)

    def headline(self) -> str:
        """The first line of the ``repr``: the method, the effects, the fitness and the
        overall rmse/noise.

        Returns
        -------
        str
        """
        m = self.metrics
        return (f"Identification ({self.method}; effects: {', '.join(self.effects.names) or 'none'}): "
                f"fitness {m['fitness']:.4g}, rmse/noise {m['rmse_over_noise']['overall']:.2f}")

    @property
    def plant(self) -> dict:
        """The fitted plant parameters ``{name: value}`` in SI units (R, L, J, B, K for
        the voltage plant)."""
        return {k: self.params[k] for k in self.space.plant.names}

    @property
    def effect_params(self) -> dict:
        """The fitted effects' parameters, ``{effect name: {param: value}}``."""
        return self.effects.nest(self.params)

    @property
    def fitness(self) -> float:
        """The weighted rmse/noise the fit minimised (1.0 is the noise floor)."""
        return self.metrics["fitness"]

    def servo(self) -> ServoParams:
        """The fitted plant and the rig's constants in the simulators' form.

        Returns
        -------
        ServoParams
        """
        return self.space.plant.servo(self.plant, self.constants)

    def step_info(self) -> dict:
        """Rise time, settling time and overshoot of the position loop with this model
        (computed once: the text and the JSON both show them).

        Returns
        -------
        dict
            ``rise_time_s`` and ``settling_time_s`` (s), ``overshoot_percent``; each
            None where the identified loop is unstable, and ``"loop": None`` too where
            the rig states no loop gains (kp).
        """
        if getattr(self, "_step_info", None) is None:
            c = self.constants
            if "kp" not in c:   # no loop to speak of (see dataset_constants)
                return {"rise_time_s": None, "settling_time_s": None,
                        "overshoot_percent": None, "loop": None}
            try:
                self._step_info = step_info(self.servo(), c["kp"], c["kv"])
            except Exception:  # an unstable identified loop has no step metrics
                self._step_info = {"rise_time_s": None, "settling_time_s": None,
                                   "overshoot_percent": None}
        return dict(self._step_info)

    def physical(self) -> dict:
        """The plant and friction in the axis's units: ``{name: {value, unit, interval95}}``
        (J, B, Tc, T0 in kg m^2, N m s/rad, N m, N m for a torque-driven axis; M, Fv, Fc,
        F0 for a force-driven one; R, L, J, B, K and friction for the voltage plant).

        Returns
        -------
        dict
            ``{name: {"value": float, "unit": str, "interval95": [lo, hi] or None}}``;
            the interval is None where the parameter is not identifiable or fixed.
        """
        pars = (self.identifiable or {}).get("parameters", {})
        plant = self.space.plant
        # a friction in N m on the voltage plant is tc_v Ka K / R: it has an interval only
        # when R and K have theirs (with the current measured), never along the symmetry
        unseen = [n for n in plant.names if n in ("R", "K") and not (
            (pars.get(n) or {}).get("interval95") or (pars.get(n) or {}).get("fixed"))]
        out = {}
        for name, (v, unit, key, scale) in plant.physical(
                self.plant, self.effect_params, self.constants).items():
            iv = (pars.get(key) or {}).get("interval95")
            if key not in plant.names and unseen:
                iv = None
            out[name] = {"value": v, "unit": unit,
                         "interval95": None if iv is None else sorted([iv[0] * scale, iv[1] * scale])}
        return out

    def _shown_identifiable(self):
        """The intervals, the effects' in the drive's units (labrig.model.drive_units)."""
        ident = self.identifiable
        if not ident or "parameters" not in ident:
            return ident
        return {**ident, "parameters": drive_units.intervals(
            self.effects, ident["parameters"], self.space.plant.kind, self.constants)}

    def to_dict(self) -> dict:
        """The JSON of ``identify --json`` (docs/design.md, 'Commands')."""
        plant = self.space.plant
        return {"method": self.method, "effects": [e.name for e in self.effects],
                "plant": plant.kind, "axis": plant.axis,
                "units": {"position": plant.position_unit(), "speed": plant.speed_unit()},
                "params": self.plant,
                "effect_params": drive_units.to_drive(self.effects, self.effect_params,
                                                      plant.kind, self.constants),
                "physical": self.physical(),
                "fixed": sorted(self.space.fixed),
                "fitness": self.metrics["fitness"],
                "rmse_over_noise": self.metrics["rmse_over_noise"],
                "fit_percent": self.metrics["fit_percent"],
                "identifiable": self._shown_identifiable(), "nfev": int(self.result.nfev),
                "nit": int(self.result.nit), "seconds": round(self.seconds, 3),
                "seed": self.result.seed, "message": self.result.message,
                "history": [float(h) for h in self.result.history],
                "step_info": self.step_info(), "noise": self.metrics["noise"],
                "per_run": self.metrics["per_run"],
                **({"starts": self.dataset["starts"]} if self.dataset.get("starts") else {})}

    def to_json(self) -> dict:
        """What ``labrig identify --json`` prints: :meth:`to_dict` with unbounded
        intervals null and the bound and fit warnings under ``warnings``."""
        return identification_dict(self)

    def table_rows(self):
        """The Table 2 column of this fit (:func:`labrig.identification.table.comparison_table`).

        Returns
        -------
        Table
            The identifiable combinations, the parameters, the fit, the closed-loop step
            and the cost.
        """
        return comparison_table([self])

    def to_pandas(self):
        """Every parameter with its value (physical units) and whether it was fixed.

        Returns
        -------
        pandas.DataFrame
            Indexed by ``parameter`` (``"J"``, ``"deadband.d_v"``), columns ``value`` and
            ``fixed``.
        """
        return pd.DataFrame([{"parameter": n, "value": v, "fixed": n in self.space.fixed}
                             for n, v in self.params.items()]).set_index("parameter")

    def plot(self, ax=None, kind: str = "fit"):
        """The fit on its runs, or its convergence.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Draw here (``kind="fit"``: the first run only); by default on a new figure.
        kind : {"fit", "convergence"}
            ``"fit"``: the model on the runs it was fitted to (measured and simulated,
            one panel per run, at most four); ``"convergence"``: best fitness against
            iteration (JFO and PSO; CO's local starts show as a line at their fitness).
            A fit that holds no runs (``runs`` None) shows its convergence.

        Returns
        -------
        matplotlib.figure.Figure
            Not saved: the caller saves (and closes) it.
        """
        # matplotlib: ~0.24 s more to import, only for a figure
        from labrig.identification.plots import plot_convergence, plot_fit

        if kind == "fit" and self.runs:
            return plot_fit(self, self.runs, ax=ax)
        return plot_convergence([self], ax=ax)

    def model(self) -> Model:
        """The identified model (what ``-o model.json`` saves).

        Returns
        -------
        Model
            The fitted parameters, effects and constants, with the fit's record
            (method, fitness, seed, ...) in ``info``.
        """
        return Model.from_flat(self.params, self.effects, self.constants,
                               plant=self.space.plant.kind, info={
            "method": self.method, "fitness": self.metrics["fitness"],
            "rmse_over_noise": self.metrics["rmse_over_noise"],
            "fit_percent": self.metrics["fit_percent"], "noise": self.metrics["noise"],
            "seed": self.result.seed, "nfev": int(self.result.nfev),
            "identifiable": {k: self.identifiable[k] for k in self.space.plant.combinations
                             if k in self.identifiable},
            "dataset": self.dataset})
