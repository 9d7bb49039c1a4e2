"""The paper's study, in layer order: the a-priori model a user would start from and the judge
of a fit (`priors`), the code hash that keys a cell (`hashing`), the rules that decide the
paper's claims (`rules`), the arms (`arms`), one cell's work (`cells`), the judged results
(`results`) and the campaign on Dask with its report (`campaign`).
"""

__all__: list[str] = []
