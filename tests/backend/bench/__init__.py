"""Tests of backend/bench/."""
