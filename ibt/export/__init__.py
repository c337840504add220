"""Behavior Trees out of Python: drawings (graphviz), JSON files and BehaviorTree.CPP XML
and engine."""
