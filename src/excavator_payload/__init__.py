"""excavator-payload: virtual sensors that weigh the payload in an excavator's bucket while
the arm moves, from the sensors the machine already has.

Built from the thesis "Virtual sensor design for payload estimation in excavators".
"""

from excavator_payload.errors import ExcavatorPayloadError

__version__ = "0.1.0"
__all__ = ["ExcavatorPayloadError", "__version__"]
