"""Files: maps, strict readers of user files, outputs committed together."""
