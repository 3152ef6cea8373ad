"""Tests of backend/train/."""
