"""Running ``lidarctl`` in-process in a test: exit code, stdout and stderr (argparse's refusals too)."""

from lidard import cli


def run(capsys, *argv) -> tuple[int, str, str]:
    try:
        code = cli.lidarctl_main(list(argv))
    except SystemExit as exc:      # argparse's refusals
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err
