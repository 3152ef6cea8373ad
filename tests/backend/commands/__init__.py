"""Tests of backend/commands/."""
