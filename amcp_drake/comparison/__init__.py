"""Cross-backend comparison: the same algorithm in Drake and cvxpy, step by step."""
