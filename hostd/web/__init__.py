"""Status page and JSON API of a hostd node.

- :func:`hostd.web.app.create_app` -- the Flask app (page, farm view, API, OctoPrint subset,
  ``/metrics``); reads the job store and cheap snapshots of a running daemon.
- :func:`hostd.web.server.start` -- waitress in its own threads inside the daemon process.

Actions (pause, resume, cancel, estop, requeue, reorder) go through the job store's
control table, the same door the terminal commands use; uploads land in the drop folder.
"""
