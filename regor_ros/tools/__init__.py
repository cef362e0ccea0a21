"""Command-line tools: file registration, benchmark, preset files, demo publisher."""
