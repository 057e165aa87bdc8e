"""The `textile-fenicsx` command line."""

import argparse
import sys

from textile_fenicsx import __version__


def _versions(_args: argparse.Namespace) -> int:
    import dolfinx
    import petsc4py
    import ufl

    print(f"textile_fenicsx {__version__}")
    print(f"dolfinx {dolfinx.__version__} (git {dolfinx.git_commit_hash[:10]})")
    print(f"ufl {ufl.__version__}")
    print(f"petsc4py {petsc4py.__version__}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="textile-fenicsx",
        description="Predict the real geometry of a woven textile unit cell: the yarns' mid-surfaces "
        "are plates that minimise bending + tension + contact energy (Lin et al. 2012), solved "
        "with FEniCSx.",
        epilog="Run it through the project's environment from a checkout: "
        "bin/fenicsx-env textile-fenicsx ...",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")
    versions = commands.add_parser("versions", help="print the versions of the numerical stack")
    versions.set_defaults(run=_versions)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "run"):
        parser.print_help()
        return 2
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
