"""Results to readers: statistics, the paper's claims with verdicts, markdown, figures.
Reads results only."""
