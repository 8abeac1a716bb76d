"""SAE J2735 messages in UPER: the codec, typed messages in SI units, the JSON form, the editions."""
from bridges.j2735.codec import (MESSAGE_IDS, MESSAGE_TYPES, Frame, J2735Codec, J2735Error,
                                 default_codec)
from bridges.j2735.editions import DEFAULT_EDITION, EDITIONS, Edition, edition

__all__ = ["DEFAULT_EDITION", "EDITIONS", "Edition", "MESSAGE_IDS", "MESSAGE_TYPES", "Frame", "J2735Codec",
           "J2735Error", "default_codec", "edition"]

# typed messages (SI units; decode -> encode keeps the bytes)
from bridges.j2735.map import ComputedLane, Connection, IntersectionGeometry, Lane, MapData, Node  # noqa: E402
from bridges.j2735.signal_request import (AccessPoint, IntersectionStatus, Requester, RequestStatus,  # noqa: E402
                                          Requestor, RequestorType, SignalRequest, Srm, Ssm)
from bridges.j2735.spat import (AdvisorySpeed, IntersectionSignals, ManeuverAssist, Movement,  # noqa: E402
                                MovementEvent, Spat)
from bridges.j2735.sdsm import (Acceleration, DateTime, DetectedObject, ObstacleDetails, Sdsm,  # noqa: E402
                                VehicleDetails, VruDetails)

__all__ += ["ComputedLane", "Connection", "IntersectionGeometry", "Lane", "MapData", "Node",
            "AccessPoint", "IntersectionStatus", "Requester", "RequestStatus", "Requestor", "RequestorType",
            "SignalRequest", "Srm", "Ssm",
            "AdvisorySpeed", "IntersectionSignals", "ManeuverAssist", "Movement", "MovementEvent", "Spat",
            "Acceleration", "DateTime", "DetectedObject", "ObstacleDetails", "Sdsm", "VehicleDetails", "VruDetails"]
