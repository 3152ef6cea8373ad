"""Helpers the tests share: scenes, workspaces, a small disk, the fuzz tally, the add-on as a package."""
