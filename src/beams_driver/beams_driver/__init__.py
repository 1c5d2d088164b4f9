"""The BeAMS sensor: code family, exact bearing variance, edge decoder, edge-level device simulation, serial source, simulated robot."""
