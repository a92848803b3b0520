"""The types the verbs take and return, and the documents their results are written as
(pydantic models of the JSON files), for the front ends that read them back or name them
in annotations."""
from labrig.analysis.doc import AnalysisDoc
from labrig.analysis.result import AnalysisResult
from labrig.diagnosis.results.docs import DiagnosisDoc, LadderDoc, Regimes
from labrig.diagnosis.results.ladder import Ladder, LadderStep
from labrig.diagnosis.results.diagnosis import Diagnosis
from labrig.diagnosis.evidence.residuals import REGIME_TEXT
from labrig.identification.doc import IdentifyAllDoc, IdentRecord
from labrig.model.model import Model
from labrig.model.servo import ServoParams

__all__ = ["AnalysisDoc", "AnalysisResult", "DiagnosisDoc", "LadderDoc", "Regimes", "Ladder",
           "LadderStep", "Diagnosis", "REGIME_TEXT", "IdentifyAllDoc", "IdentRecord", "Model",
           "ServoParams"]
