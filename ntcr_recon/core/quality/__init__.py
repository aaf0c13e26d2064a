"""How sure a result is: coded findings, the checks over a reconstruction's trace, metrics against truth."""
