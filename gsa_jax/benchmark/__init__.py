"""The vmapped seed benchmark's measurements, workers and figure (`gsa bench`)."""
