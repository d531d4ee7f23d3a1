"""Questionnaires HRI studies pair with the telepresence system: QAM (expected vs perceived), SUS, NASA-TLX,
Godspeed and the SSQ, each a file of one instrument format (`instrument`) a lab can add to. Each reads a CSV/JSON
answer sheet (`sheets`), scores it by its published rule, and reports tables, JSON (pydantic models) and charts
(`plots`). The CLI is `vr-teleop qam|sus|tlx|godspeed template|score`."""

from .godspeed import GodspeedDefinition, load_godspeed_definition, score_godspeed, series_means
from .instrument import PREFER_NOT, AnswerError, Instrument, check_answers, load_instrument, score
from .qam import QAMDefinition, QAMReport, load_qam_definition, score_qam
from .sheets import AnswerRow, Sheet, SheetError, SheetIssue, SheetSpec, read_sheet, write_template
from .stats import PairedTest, describe, rank_biserial, wilcoxon_paired
from .sus import load_sus_definition, score_sus, sus_score
from .tlx import load_tlx_definition, raw_tlx, score_tlx, weighted_tlx

__all__ = [
    "PREFER_NOT", "AnswerError", "Instrument", "check_answers", "load_instrument", "score",
    "AnswerRow", "GodspeedDefinition", "PairedTest", "QAMDefinition", "QAMReport", "Sheet", "SheetError",
    "SheetIssue", "SheetSpec", "describe", "load_godspeed_definition", "load_qam_definition",
    "load_sus_definition", "load_tlx_definition", "rank_biserial", "raw_tlx", "read_sheet", "score_godspeed",
    "score_qam", "score_sus", "score_tlx", "series_means", "sus_score", "weighted_tlx", "wilcoxon_paired",
    "write_template",
]
