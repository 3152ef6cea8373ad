"""Tests of backend/eval/."""
