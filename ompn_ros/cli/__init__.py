"""Command-line entry points: ompn_train, ompn_collect, ompn_segment, ompn_ensemble, ompn_closed_loop."""
