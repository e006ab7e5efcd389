"""Model library: the lecture examples, pendulums, chains, delta robot, test-set problems."""
