"""The emergency vehicle's on-board unit app (EVSP): MAP + own position -> signed SRMs; SSM and SPaT read.

A participant process like the RSU and AV apps, importing only `bridges`.
"""
