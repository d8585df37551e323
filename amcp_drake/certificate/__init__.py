"""Certificates: every claim of the paper re-checked from a recorded run with numpy/scipy only
(``certify``, ``claims``, ``tube``, ``section4``), and the bundle written from them (``report``,
``templates/``, the schema in ``amcp_drake/data/certificate.schema.json``). Never imports a backend."""
