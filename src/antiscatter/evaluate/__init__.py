"""Accuracy against ground truth: matching, metrics, drivers and the scoreboard."""

from ..assignment import gates, match
from .metrics import FrameScore, hole_mask, prf, score_frame, summarise
from .runs import Matching, evaluate_csv, evaluate_folder, evaluate_pairs, evaluate_scenario, evaluate_source

__all__ = ["match", "gates", "FrameScore", "score_frame", "summarise", "prf", "hole_mask", "Matching",
           "evaluate_csv", "evaluate_folder", "evaluate_source", "evaluate_pairs", "evaluate_scenario"]
