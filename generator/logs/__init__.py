"""Your own logs: :mod:`.importers` reads ULog, CSV, Parquet and flight folders; :mod:`.offline` imports them
into datasets and attacks them in csv mode."""
