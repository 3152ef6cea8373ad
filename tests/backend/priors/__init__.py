"""Tests of backend/priors/."""
