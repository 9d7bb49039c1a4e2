"""How results are shown: Rerun recordings of fits (`report`) and the campaign's figures and
report.html (`figures`).
"""

__all__: list[str] = []
