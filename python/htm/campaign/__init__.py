"""Virtual test campaigns: a base test spec, sweeps (grid, Latin hypercube) over spec fields and rig
parameters and Monte Carlo over material scatter, run as chunks of simulated tests on local cores or
a Dask cluster into one table of the store.

    htm campaign examples/campaign_ct.toml                          # this machine, all cores
    htm campaign examples/campaign_ct.toml --cluster tcp://HOST:8786  # a Dask cluster

`spec.py` expands a campaign file into its tests, `engine.py` runs chunks and writes the table,
`cluster.py` sends chunks to Dask, `plot.py` draws life against the swept fields, `cli.py` is the
command; `lifeband.py` (+ `lifeband_cli.py`, `htm life-band`) builds a crack-growth life
distribution from a specimen set as a campaign, and `stress.py` checks concurrent catalogue writers.
"""
