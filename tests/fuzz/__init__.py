"""The fuzz harness of issue 22 (tests/test_fuzz.py): mutations per file kind
(:mod:`.mutate`), the commands that read each kind and the replay of a case (:mod:`.cases`),
the forked runner that classifies the outcome (:mod:`.runner`), the base files (:mod:`.bases`)
and the counts (:mod:`.stats`, :mod:`.report`)."""
