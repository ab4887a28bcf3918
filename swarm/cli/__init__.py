"""The `swarm` command: parser (swarm.cli.parser), one module per command, shared pieces below them
(swarm.cli.common, swarm.cli.console); swarm.cli.main is the entry point."""
