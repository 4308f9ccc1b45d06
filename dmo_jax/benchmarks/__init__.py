"""Speed benchmarks behind ``bin/benchmark`` (BENCHMARKS.md, "Prediction speed", "Networks and cost"), and the plain reference
implementations they time the shipped code against. Nothing in the library imports them."""
