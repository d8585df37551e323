"""Studies built on the library: benchmarks, the adaptive-vs-robust baseline, the Proposition 23
figure, verification campaigns and their SQLite store. Nothing below this layer imports it."""
