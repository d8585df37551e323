"""Cross-backend comparison (issue 4): the same algorithm in Drake and cvxpy, step by step."""
