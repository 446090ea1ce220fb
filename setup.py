"""ament_python package art_gyro_calibration; also installable with pip."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'art_gyro_calibration'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*']),
    # PEP 561: the package's type hints are for its users too; gyro_node's Fast DDS profile (ros/node.py).
    package_data={PACKAGE: ['py.typed', 'ros/fastdds_profile.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', sorted(glob('config/*.yaml'))),
        ('share/' + PACKAGE + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    python_requires='>=3.10',
    # The runtime a robot installs (the node, the driver, the fake gyro) needs only these;
    # the offline tools (art_gyro_calibration.analysis: fit, trace, simulate, plots) need the extra 'analysis';
    # the studies in research/ need 'research' beside it (h5py: research/importers.py reads NetCDF-4 records).
    install_requires=['setuptools', 'numpy', 'pyyaml', 'pyserial'],
    extras_require={'analysis': ['scipy', 'matplotlib', 'threadpoolctl', 'rosbags'], 'research': ['h5py']},
    zip_safe=True,
    maintainer='art_gyro_calibration developers',
    maintainer_email='dev@art-gyro.local',
    description='Calibrated yaw rate from a KVH E-Core RD2100 fibre optic gyro, after ART\'s calibration report',
    license='Apache-2.0',
    tests_require=['pytest', 'hypothesis', 'allantools'],
    entry_points={
        'console_scripts': [
            'gyro_node = art_gyro_calibration.ros.node:main',
            'fake_gyro = art_gyro_calibration.fake_gyro:main',
            'fake_rd2100 = art_gyro_calibration.fake_gyro:main',   # its name before it simulated KVH units too
            'calibrate = art_gyro_calibration.analysis.cli:main',
            'imu_echo = art_gyro_calibration.ros.monitor:main',
        ],
    },
)
