"""Trained tuners: a policy learned over a plant family that answers verified gains for a new plant."""
