"""Synthetic captures: the Cycles room and the procedural scene family, rendered with exact ground truth."""
