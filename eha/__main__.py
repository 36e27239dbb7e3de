from eha.cli import main

main()
