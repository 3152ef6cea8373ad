"""Tests of igs_contract: what the add-on and the backend both read and write."""
