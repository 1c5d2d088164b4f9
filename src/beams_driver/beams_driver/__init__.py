"""The BeAMS sensor: codes, exact variance, decoder, device simulation, serial source, simulated robot."""
