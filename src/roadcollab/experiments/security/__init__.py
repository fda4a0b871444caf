"""The attack and secure-aggregation studies (``roadcollab attack``)."""
