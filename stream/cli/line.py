"""CLI commands of a production line: ``certs`` (its CA and role certificates) and ``router``.

robocal certs --out /etc/robocal/certs --hosts router.cell1.lan
robocal router --config /etc/robocal/zenohd.json5
"""

from __future__ import annotations

import argparse

from stream.cli._base import Command, add_json_flag, emit
from stream.log import JsonLogger

_ALL_ROLES = "robot,tracker,daq,learner,dashboard,compensation,router"


class CertsCommand(Command):
    name = "certs"
    uses_torch = False
    help = "make a line's CA and one certificate per role for the TLS bus (keys 0600)"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--out", required=True, help="folder for ca.pem and <role>.pem/.key")
        parser.add_argument(
            "--roles",
            default=_ALL_ROLES,
            help=f"comma list of certificate names: roles, or role-suffix for a further client "
            f"of a role (default {_ALL_ROLES}); the CA in --out is reused when there",
        )
        parser.add_argument(
            "--hosts",
            default="",
            help="comma list of names/IPs clients reach the router by (localhost and "
            "127.0.0.1 are always in)",
        )
        parser.add_argument("--days", type=int, default=825, help="validity (days)")
        add_json_flag(parser)

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.security import make_line_certs, parse_roles

        hosts = tuple(h.strip() for h in args.hosts.split(",") if h.strip())
        certs = make_line_certs(args.out, parse_roles(args.roles), hosts, args.days)
        result = {
            "ca": str(certs.ca),
            "ca_key": str(certs.ca_key),
            "roles": {r: {"cert": str(c), "key": str(k)} for r, (c, k) in certs.roles.items()},
        }
        emit(
            result,
            args.json,
            f"wrote {certs.ca} and {len(certs.roles)} role certificates "
            f"({', '.join(certs.roles)}) into {args.out}",
        )
        return 0


class RouterCommand(Command):
    name = "router"
    uses_torch = False
    help = "run the line's Zenoh router (TLS, access control) until SIGTERM/SIGINT"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--config", required=True, help="router config (deploy/zenohd.json5)")
        parser.add_argument(
            "--listen", action="append", default=[], help="replace the listen endpoints"
        )
        parser.add_argument(
            "--certs", default=None, help="folder with ca.pem, router.pem, router.key"
        )

    def take_action(self, args: argparse.Namespace) -> int:
        from stream.router import router_config, run_router

        zc = router_config(args.config, tuple(args.listen), args.certs)

        log = JsonLogger()
        return run_router(zc, lambda endpoints: log.info("router_started", listen=endpoints))


COMMANDS: tuple[type[Command], ...] = (CertsCommand, RouterCommand)
