"""Everything that crosses a process boundary: wire formats, security, transports.

The master and the apps (rsu_app, av_app) both import this package and nothing
else from each other (DESIGN §1).
"""
