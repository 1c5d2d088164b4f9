"""ToTal triangulation (thesis ch. 6) with 1/|D| gating and pose covariance."""
