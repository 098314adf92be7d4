"""Navigation methods (ins, vo, lc, tc, 3d): filter + models + front end wired together."""
