"""Results read and judged, one subpackage per concern: sweeps/ (a sweep's results read, rliable statistics, tables
and figures, controller scores), verdicts/ (is K enough: Yuen's test, the sequential design, the baseline, the answer's
decisions and its report; the loop that trains the answer: gsa_jax.orchestration), robustness/ (controllers under shifts and pushes), quoting/ (numbers in pages from the committed
tables); the last three import sweeps/ and not each other. sweep_report (every table and figure of a sweep) sits above
them. Imports the layers below."""
