"""Examples that build an app on `bridges` alone (docs/writing-an-app.md); not part of the installed packages."""
