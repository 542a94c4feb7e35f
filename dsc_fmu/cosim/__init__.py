"""Co-simulation of the three FMUs: the master, other masters' exchange schemes, the monolithic
reference solution, result columns, metrics, files and figures of a run."""
