"""The reproduction of the paper's figures and tables (``roadcollab reproduce``)."""
