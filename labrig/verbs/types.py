"""The types the verbs take and return (each result reads its own JSON back:
``from_json``), and the fit's record, for the front ends that read them back or name them
in annotations."""
from labrig.analysis.result import AnalysisResult
from labrig.diagnosis.results.ladder import Ladder, LadderStep
from labrig.diagnosis.results.diagnosis import Diagnosis, Regimes
from labrig.diagnosis.evidence.residuals import REGIME_TEXT
from labrig.identification.doc import IdentifyAllDoc, IdentRecord
from labrig.model.model import Model
from labrig.model.servo import ServoParams

__all__ = ["AnalysisResult", "Regimes", "Ladder",
           "LadderStep", "Diagnosis", "REGIME_TEXT", "IdentifyAllDoc", "IdentRecord", "Model",
           "ServoParams"]
