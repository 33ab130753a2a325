"""Campaigns: many runs of a scenario over seeds, axes and sampled settings, on a distributed engine,
into one results table (``spec``, ``worker``, ``engine``, ``coordinator``, ``results``), ranked by
the leaderboard (``leaderboard``)."""
