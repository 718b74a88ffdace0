"""The command-line jobs: each runs one verb's work (simulate and export, evaluate, bench,
the check tables) on top of the library; ``hyperbones.cli`` only parses arguments and calls
them."""
