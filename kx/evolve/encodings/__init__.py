"""The built-in encodings of the run loop (:class:`kx.evolve.encoding.Encoding`), one module each:
:mod:`~kx.evolve.encodings.neat` (``method = "neat"``), :mod:`~kx.evolve.encodings.hyperneat`
(``"hyperneat"``) and :mod:`~kx.evolve.encodings.cma_es` (``"cma_es"``). :mod:`kx.evolve.registry`
registers them; importing this package loads none of them."""
