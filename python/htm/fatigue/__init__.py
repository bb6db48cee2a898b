"""ASTM E647 reduction, crack-growth law fitting, closing-the-loop analysis and test reports."""
from htm.fatigue.data import CrackData, Setup, read_a_n
from htm.fatigue.e647 import Reduced, paris_region_ii, reduce, threshold
from htm.fatigue.laws import Model, Points, fit_life, fit_rate
from htm.fatigue.report import write_test_report

__all__ = ["CrackData", "Setup", "read_a_n", "Reduced", "reduce", "threshold", "paris_region_ii",
           "Model", "Points", "fit_rate", "fit_life", "write_test_report"]
