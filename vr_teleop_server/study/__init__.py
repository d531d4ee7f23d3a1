"""HRI user-study framework: perception, decision, action and metrics modules."""
