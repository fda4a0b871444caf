"""Algorithm 1, the relay engine and fleet fusion."""
