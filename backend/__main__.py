from backend.core import signals

signals.install()  # before the imports below: a Ctrl-C while they load is a cancel, not a traceback

from backend.commands.cli import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main())
