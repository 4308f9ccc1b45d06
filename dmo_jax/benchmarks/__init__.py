"""Speed benchmarks behind ``bin/benchmark`` (BENCHMARKS.md, "Networks and cost", "Prediction
speed"), and the plain reference implementations they time the shipped code against. Nothing in
the library imports them."""
