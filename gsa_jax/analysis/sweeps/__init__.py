"""A sweep's results: reading and merging them, rliable statistics, the tables and figures, the committed
controllers' scores, extraction and re-scoring."""
