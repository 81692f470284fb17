"""``guadal serve``: the mission database in a browser, live.

``server`` decides whether and how to start (``security`` is the access policy), ``app`` holds
the routes, ``reader`` shapes database rows for the page, ``controls`` turns an operator's click
into a request the running mission picks up, ``downloads`` reuses the report's exports.
The pages and their vendored libraries are in ``static/``: nothing is fetched from the internet.
"""
