"""The effect catalogue as a result a user can read: each effect's parameters, what it
is in the rig, where it shows in the residuals and the experiment that confirms it."""
from __future__ import annotations

from dataclasses import dataclass, field

from labrig.core.display import Displayable
from labrig.core.tables import Table
from labrig.model.effects import CATALOGUE


@dataclass(repr=False)
class Catalogue(Displayable):
    """The effects a model can hold (``lr.effects()``); ``[name]`` gives the class.

    Attributes
    ----------
    effects : dict
        Name -> effect class, in the catalogue's order.

    ``to_pandas()`` is the table (name, stage, parameters, physics); a notebook shows it.

    Examples
    --------
    >>> import labrig as lr
    >>> cat = lr.effects()
    >>> cat["deadband"].name
    'deadband'
    """

    effects: dict = field(default_factory=dict)

    @classmethod
    def builtin(cls) -> "Catalogue":
        """The built-in effect catalogue (what ``lr.effects()`` gives).

        Returns
        -------
        Catalogue
            Every built-in effect, in the catalogue's order (user effects not included).
        """
        return cls(dict(CATALOGUE))

    def __getitem__(self, name: str):
        return self.effects[name]

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    def headline(self) -> str:
        """The first line of the ``repr``: how many effects.

        Returns
        -------
        str
        """
        return f"Catalogue: {len(self.effects)} effects"

    def table_rows(self) -> Table:
        """The catalogue as a table.

        Returns
        -------
        Table
            One row per effect: its name, stage, parameters with their units, and what
            it is.
        """
        t = Table("the effect catalogue", ["effect", "stage", "parameters", "what it is"])
        for name, e in self.effects.items():
            params = ", ".join(f"{p.name} ({p.unit})" for p in e.params)
            t.rows.append([name, e.stage, params, e.summary])
        return t

    def to_pandas(self):
        """The catalogue as a DataFrame, one row per effect.

        Returns
        -------
        pandas.DataFrame
            Columns ``effect``, ``stage``, ``parameters`` (a list of names),
            ``summary``, ``signature`` (where it shows in the residuals) and
            ``experiment`` (the one that confirms it).
        """
        import pandas as pd  # ~0.19 s to import, for a notebook's table only

        return pd.DataFrame([{"effect": n, "stage": e.stage,
                              "parameters": [p.name for p in e.params],
                              "summary": e.summary, "signature": e.signature,
                              "experiment": e.experiment} for n, e in self.effects.items()])

    def _figure_for_html(self):
        return None
