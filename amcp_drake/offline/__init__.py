"""The offline design (docs/explanation/paper.md §4-§6, Appendix A.1): K, P, X0, w̄, f̄, X_f, μ (``design``) and its
independent verification with numpy/scipy (``checks``). Imports the model and the backends only."""
