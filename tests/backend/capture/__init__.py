"""Tests of backend/capture/."""
