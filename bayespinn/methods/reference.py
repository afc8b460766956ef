"""The summary key of the reference method (the modal one, `methods.modal`), in a module that imports
nothing.

The reference's own computations (`uq.modal_mcmc`, `uq.girder_posterior`, `uq.girder_reference`,
`uq.priors`) label their posteriors with it, and `methods.modal` imports them, so they cannot import the
registry (`bayespinn.methods`) without an import cycle; they, `methods.modal` and the registry all read it
from here. Everything that judges a method against the reference reads `bayespinn.methods.REFERENCE_KEY`.
"""

#: the summary key of the modal reference's posteriors, the one the other methods are judged against
REFERENCE_KEY = "modal_mcmc"
