"""Fleet diagnosis: `htm diagnose` over a folder of records from several machines and dates, the
identified parameters kept per machine and date in the store's catalogue, and their history per
machine with a drift flag (`htm fleet diagnose FOLDER`, `htm fleet trend MACHINE`).

`catalogue.py` reads and writes the fleet table, `drift.py` judges a parameter's latest value
against its own history, `cli.py` is the command.
"""
