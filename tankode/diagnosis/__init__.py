"""Diagnosis: what entered or left the tank unmetered, what the simulation gets wrong, and why.

``diagnose(runs) -> Diagnosis`` runs every step: the inventory audit (``audit_run``: unmetered
mass and heat from the sensors and CoolProp, no heat-transfer law), then the dynamic search
(calibration, score test, refits, held-out evidence), and the ``Verdict`` that combines them
(``tankode.diagnosis.verdict``). ``write_report(diagnosis, out_dir)`` writes ``report.json``,
``report.md``, the figures and the extended model. The steps are public for notebooks:
``audit_run``, ``calibrate``, ``residual_report``, ``score_tests``, ``bootstrap_gain``. How
residuals are weighed is a strategy: ``SensorNoise()`` (default) or ``ModelError()``.
"""

from .audit import AuditConfig, RunAudit, audit_run, with_audited_wall
from .data import HoldOutTail, LeaveOneRunOut, Observed
from .diagnose import DEFAULT_CANDIDATES, Candidate, Diagnosis, DiagnosisConfig, Thresholds, calibrate, diagnose
from .evidence import bootstrap_gain, information_criteria, score_tests
from .fit import Fit, fit
from .forward import Problem
from .report import write_report
from .verdict import Verdict
from .residuals import heldout_rms_sigma, ljung_box, residual_report
from .weighting import ModelError, SensorNoise

__all__ = [
    "AuditConfig", "RunAudit", "Verdict", "audit_run", "with_audited_wall",
    "DEFAULT_CANDIDATES", "Candidate", "Diagnosis", "DiagnosisConfig", "Fit", "HoldOutTail", "LeaveOneRunOut", "ModelError", "Observed", "Problem",
    "SensorNoise",
    "Thresholds", "bootstrap_gain", "calibrate", "diagnose", "fit", "heldout_rms_sigma", "information_criteria",
    "ljung_box",
    "residual_report", "score_tests", "write_report",
]
