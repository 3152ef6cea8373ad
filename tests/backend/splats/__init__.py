"""Tests of backend/splats/."""
