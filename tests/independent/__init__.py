"""An independent simulator of rigid one-degree-of-freedom joints and a battery of logs for the discrepancy
analysis; it shares no physics code with ``sim``, ``models`` or ``controllers``."""
