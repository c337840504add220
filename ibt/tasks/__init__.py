"""The task catalogue: every fact about one environment in one entry (`Task`)."""
