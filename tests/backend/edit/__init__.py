"""Tests of backend/edit/."""
