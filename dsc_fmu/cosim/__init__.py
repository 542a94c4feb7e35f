"""Co-simulation of the three FMUs: one loop with our master's and other masters' exchange as policies, model
exchange, the monolithic reference solution, result columns, metrics, files and figures of a run."""
