"""``tcs-passwd [NAME]``: print a salted password hash for the ``[[users]]`` table.

The password is read without echo (or from standard input when it is not a terminal) and
never written anywhere; paste the printed ``[[users]]`` block into the hardware file.
"""

from __future__ import annotations

import argparse
import getpass
import sys

from tcs import __version__
from tcs.config.passwords import hash_password


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="tcs-passwd", description=__doc__.splitlines()[0])
    p.add_argument("name", nargs="?", default="observer", help="user name for the printed block")
    p.add_argument("--rlevel", type=int, default=3,
                   help="read level of the user: lower is more privileged; 0 reads everything, "
                        "9 the minimum (default: %(default)s)")
    p.add_argument("--wlevel", type=int, default=3,
                   help="write level: 0 everything, 1 configuration (LOCAL site, CONFIG), "
                        "3 operation (axes, dome, pointing) (default: %(default)s)")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    args = p.parse_args(argv)
    if sys.stdin.isatty():
        password = getpass.getpass("password: ")
        if getpass.getpass("again: ") != password:
            print("tcs-passwd: the passwords differ", file=sys.stderr)
            return 1
    else:
        password = sys.stdin.readline().rstrip("\n")
    if not password:
        print("tcs-passwd: empty password refused", file=sys.stderr)
        return 1
    print(f'[[users]]\nname = "{args.name}"\npassword = "{hash_password(password)}"\n'
          f"rlevel = {args.rlevel}\nwlevel = {args.wlevel}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
