"""Tests of the backend, one folder per room of backend/."""
