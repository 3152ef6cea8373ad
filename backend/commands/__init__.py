"""The command layer: ``igs <command>`` parses its options into the library's typed configs and
calls library functions; :mod:`backend.commands.cli` holds the parser and ``main``."""
