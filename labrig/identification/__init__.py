"""Problem-agnostic optimisers for system identification (JFO, PSO, CO)."""
