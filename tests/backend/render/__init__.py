"""Tests of backend/render/."""
