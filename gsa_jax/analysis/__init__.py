"""Results read and judged: rliable statistics, a sweep's tables and figures, extraction, scoring,
robustness. Imports the layers below."""
