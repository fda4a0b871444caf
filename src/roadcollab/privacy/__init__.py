"""Algorithm 2 (obfuscation), attacks on the exchanges, conventional baselines."""
