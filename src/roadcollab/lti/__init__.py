"""Linear-system kernels: discretisation, frequency responses, realisations, 2x2 batch algebra,
ARX identification. Pure functions and thin containers; imports nothing else from the package."""
