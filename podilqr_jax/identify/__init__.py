"""Identification: the information state, the least-squares and IV ARMA fits, the exact
linearisation, and the strategies (data-based, exact) the driver calls."""
