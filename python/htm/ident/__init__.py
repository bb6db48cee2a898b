"""Identification: measurement records (DATA_FORMAT.md) and, later, model fitting and diagnosis."""
from htm.ident.records import Record, read_record, validate_record, write_record

__all__ = ["Record", "read_record", "validate_record", "write_record"]
