"""Tests of backend/synth/."""
