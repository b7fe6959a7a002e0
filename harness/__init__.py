"""What the tests and the benchmarks both use: the service run as real processes, a throw-away
PostgreSQL, upload files built in code, the README's examples as commands. Neither imports the
other; both import this."""
