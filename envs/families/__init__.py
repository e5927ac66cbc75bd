"""The task families: one module each, defining its record type (a TaskRecord subclass, envs/families/record.py) and
the names that resolve to it (its ENTRIES, or a name PREFIX); envs/registry.py maps names to records from them."""
