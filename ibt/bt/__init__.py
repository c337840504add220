"""The Behavior Tree model every step downstream consumes: nodes, executors and node counts."""
