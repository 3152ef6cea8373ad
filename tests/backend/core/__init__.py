"""Tests of backend/core/."""
