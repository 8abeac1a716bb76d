"""`python -m av_app`: see av_app.cli."""
import sys

from av_app.cli import main

sys.exit(main())
