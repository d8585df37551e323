"""The online loop: the controller's steps (i)-(iv) with (7)/(9)/(25), (12), (20), (21)
(``controller``), persistent excitation of Section 4.2 (``excitation``), and closed-loop simulation of
(1) with its recorded ``Trajectory`` (``simulate``). Imports the model, the offline design and the
backends; never the certificate, the studies or the CLI."""
