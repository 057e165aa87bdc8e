"""The command line: entry point and exit codes (main), one parser per command (arguments), the
commands (commands, volume_commands). `textile-fenicsx` runs `textile_fenicsx.cli.main:main`.
"""
