"""Fleet replay: many recorded traces through the ECU on Dask (vecu.campaign.cluster), each diffed
against what was recorded and judged, with a fleet table, report and JUnit (docs/replay.md)."""
