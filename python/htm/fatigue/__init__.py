"""ASTM E647 reduction, crack-growth law fitting, closing-the-loop analysis and test reports."""
