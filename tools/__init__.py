"""Python tools of vkunroll, one room per purpose (tools/README.md). Run from the repository root as
`python3 -m tools.ROOM.SCRIPT`: the rooms import each other as packages, no sys.path edits."""
