"""The round and the search: the linear start, the candidates, their re-fits from
several starts, the round that judges them (``diagnose``) and the search that plays
rounds, pairs and revisions (``diagnose --auto``)."""
