"""The MCAP log: its writer and reader, the topics and schemas a run records, and its metadata records."""
