"""labrig: a hardware-in-the-loop acquisition and identification station for DC-servo labs.

``import labrig as lr`` gives the verbs of the lab (docs/api.md)::

    runs = lr.read_runs("data/sweep_default")
    res = lr.analyse(runs)                       # deadband, Km, tau_m
    fit = lr.identify(runs)                      # the linear model (CO)
    diag = lr.diagnose(runs, fit)                # which effect is missing, with evidence
    final = lr.auto(runs)                        # the loop to the end, with its ladder

Every result shows a summary as text, and its tables and figure in a notebook. The
names are loaded on first use, so ``import labrig`` stays quick.
"""
from labrig.core.memory import keep_freed_memory
from labrig.core.parallel import one_blas_thread
from labrig.core.version import __version__

# a notebook's fits as the command line's: numpy's BLAS held to one thread (the same last
# digits, and no idle BLAS thread spinning on the core the second fit needs) and freed
# memory kept for the next call (labrig.core.parallel, labrig.core.memory; docs/api.md)
one_blas_thread()
keep_freed_memory()

#: public name -> module that defines it
_PUBLIC = {name: "labrig.verbs" for name in (
    "sweep", "read_runs", "analyse", "identify", "add_effect", "remove_effect", "diagnose",
    "auto", "propose", "decide", "compare", "ladder", "effects", "load_model", "try_effect",
    "set_by_hand", "ask_until_sure")}
_PUBLIC.update({
    "Model": "labrig.model.model", "Run": "labrig.io.runs", "Effect": "labrig.model.effects",
    "Param": "labrig.model.effect_base",
    "AnalysisResult": "labrig.analysis.result", "Identification": "labrig.identification.fit",
    "Diagnosis": "labrig.diagnosis.results.diagnosis", "AutoDiagnosis": "labrig.diagnosis.loop.auto",
    "Evaluation": "labrig.diagnosis.evidence.evaluation", "Ladder": "labrig.diagnosis.results.ladder",
    "Proposal": "labrig.design.proposal", "Catalogue": "labrig.model.catalogue",
    "LabrigError": "labrig.core.errors", "UserError": "labrig.core.errors",
})

__all__ = list(_PUBLIC) + ["__version__"]


def __getattr__(name):
    if name in _PUBLIC:
        import importlib

        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'labrig' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
