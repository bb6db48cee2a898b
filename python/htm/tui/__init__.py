"""The `htm-tui` operator console (Textual): setup, install, run, results, diagnose."""
